"""A rotation-only natural fit refitted with the camera's translation as a nuisance
(:func:`refit_with_translation`): the choice of the model, a hold-out of whole frame pairs,
the refit on every pair and its honest sigma (:mod:`calib.natural.motion_sigma`).

**Hold-out** (as :func:`calib.fit.calibrate`): the frame pairs of
:func:`calib.data.holdout_mask` are left out; the translation fit on the others (from both
the rotation-only estimate and the axis search's start, the lower robust cost wins) predicts
them with its calibration, each held-out pair (``per-pair``) or segment (``travel``) getting
its own nuisance translation refitted from its own tracks at that calibration (a translation
is a nuisance of the data, not part of the calibration; the depths are eliminated as in the
fit). Their epipolar distances are the hold-out statistics. The fit is then repeated on every
pair, warm-started from the training estimate (what is written, ``options.refit_all``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from calib.data import StreakSet, holdout_mask, relative_gyro
from calib.fitcore import FitOptions
from calib.natural.motion import (
    AUTO_MODEL,
    AUTO_RATIO,
    MotionProblem,
    TranslationFit,
    cauchy_weights,
    fit_translation,
    mean_squares,
    prefers_translation,
)
from calib.natural.motion_sigma import translation_sigma
from calib.natural.sigma import gyro_scale_known
from calib.params import THETA_NAMES, apply_theta, parse_fit, theta_from
from calib.problem import ResidualModel, choose_substeps
from calib.result import ErrorStats, named

if TYPE_CHECKING:
    from calib.natural.pipeline import NaturalResult

#: Robust re-weighting rounds of a held-out pair's own nuisance translation.
HOLDOUT_ROUNDS = 3


def residual_model(
    initial: Calibration, streaks: StreakSet, gyro: GyroTrace, options: FitOptions
) -> tuple[ResidualModel, np.ndarray, float]:
    """The rotation model a translation fit evaluates (as the rotation-only fit's, from the
    fit's initial calibration) and the pixel conditioning ``(centre, f)`` of its epipoles."""
    cam = initial.camera
    g = relative_gyro(gyro.upsampled(options.gyro_upsample), streaks.t0_s)
    n_sub = choose_substeps(streaks, cam.height, max(2 * cam.readout_s, 0.05))
    model = ResidualModel(g, initial.R_cam_imu, cam.dist, cam.height, n_sub)
    return model, np.array(cam.intrinsics[2:4], float), float(cam.intrinsics[0])


@dataclass(frozen=True)
class HeldOut:
    """Epipolar distances (px) of held-out tracks at a given calibration."""

    residual_px: np.ndarray
    inlier: np.ndarray
    usable: np.ndarray


def predict_held_out(
    model: ResidualModel,
    streaks: StreakSet,
    theta: np.ndarray,
    centre: np.ndarray,
    f: float,
    travel: bool,
) -> HeldOut:
    """Held-out tracks predicted by ``theta``: their own nuisance translation (per pair or
    per travel segment) refitted at ``theta`` with robust weights, the calibration held."""
    pb = MotionProblem(model, streaks, centre, f, travel)
    w = pb.usable.astype(float)
    r = np.zeros(len(streaks))
    for _ in range(HOLDOUT_ROUNDS):
        E = pb.epipoles(theta, w)
        r = pb.residual(theta, E)
        w, _ = cauchy_weights(r, pb.usable)
    return HeldOut(r, w > 0, pb.usable)


def _best(
    model: ResidualModel,
    streaks: StreakSet,
    starts: tuple[np.ndarray, ...],
    fit_idx: tuple[int, ...],
    centre: np.ndarray,
    f: float,
    travel: bool,
) -> tuple[TranslationFit, int]:
    from blurtrack.features.pairs import concurrently

    fits = concurrently(
        [
            partial(fit_translation, model, streaks, t0, fit_idx, centre, f, travel=travel)
            for t0 in starts
        ]
    )
    k = min(range(len(fits)), key=lambda i: fits[i].cost)
    return fits[k], k


def refit_with_translation(
    nat: NaturalResult, gyro: GyroTrace, options: FitOptions, mode: str
) -> NaturalResult:
    """``nat`` (a rotation-only natural fit) refitted with a translation nuisance when
    ``mode`` is ``per-pair`` or ``travel``, or ``auto`` and the data ask for it
    (:mod:`calib.natural.motion`'s docstring): from both the rotation-only estimate and the
    axis search's start (the lower robust cost wins), with a hold-out of whole frame pairs
    (each predicted with its own refitted translation), the refit on every pair and the sigma
    of :mod:`calib.natural.motion_sigma`. Track errors are epipolar distances (module
    docstring)."""
    res, streaks = nat.result, nat.streaks
    base = res.initial
    model, centre, f = residual_model(base, streaks, gyro, options)
    th_rot = np.array([res.values[n] for n in THETA_NAMES])
    ms_rot, ms_epi = mean_squares(model, streaks, th_rot, centre, f)
    wanted = mode != "auto" or prefers_translation(ms_rot, ms_epi)
    chosen = AUTO_MODEL if mode == "auto" else mode
    travel = chosen == "travel"
    info: dict[str, Any] = {
        "mode": chosen if wanted else "none",
        "chosen_by": "data" if mode == "auto" else "option",
        "ms_rotation_px2": ms_rot,
        "ms_epipolar_px2": ms_epi,
        "ratio": ms_rot / ms_epi if ms_epi > 0 else float("inf"),
        "auto_ratio": AUTO_RATIO,
    }
    if not wanted:
        return replace(nat, translation=info)
    fit_idx = parse_fit(options.fit)
    # Where the pure-rotation model could not decide the axes (the common heading did), its
    # fit is biased by the parallax it could not explain: only the axis search's start is
    # tried (the phone drive: 40 iterations from it without converging, a worse cost).
    heading = (nat.axes.decision or {}).get("model") == "common heading"
    starts = (theta_from(base),) if heading else (th_rot, theta_from(base))
    held = holdout_mask(streaks.frame, options.holdout_fraction)
    train, test = streaks.subset(~held), streaks.subset(held)
    hold_fit: TranslationFit | None = None
    ho: HeldOut | None = None
    if options.holdout_fraction > 0 and len(test):
        hold_fit, k = _best(model, train, starts, fit_idx, centre, f, travel)
        ho = predict_held_out(model, test, hold_fit.theta, centre, f, travel)
        if options.refit_all:
            best = fit_translation(
                model, streaks, hold_fit.theta, fit_idx, centre, f, travel=travel
            )
            fitted_on = streaks
        else:
            best, fitted_on = hold_fit, train
    else:
        best, k = _best(model, streaks, starts, fit_idx, centre, f, travel)
        fitted_on = streaks
    info["start"] = "rotation-only fit" if k == 0 and not heading else "axis search"
    if heading:
        info["starts_tried"] = "axis search only (the axes were decided by the common heading)"
    info["epipoles"] = best.epipoles.tolist()
    pb = MotionProblem(model, fitted_on, centre, float(f), travel)
    w, _ = cauchy_weights(best.residual_px, pb.usable)
    scale_known = gyro_scale_known(base)
    sigma, sigma_info = translation_sigma(pb, best.theta, best.epipoles, fit_idx, w, scale_known)
    r = np.abs(best.residual_px)
    fitted = tuple(THETA_NAMES[i] for i in fit_idx)
    warnings = [
        f"translation modelled ({chosen}): track errors and the hold-out's are epipolar "
        "distances, the hold-out's nuisance translation refitted per held-out "
        + ("pair" if chosen == "per-pair" else "segment")
    ]
    if ho is None:
        warnings.append("no hold-out (--holdout 0 or too few frame pairs)")
    if not best.converged:
        warnings.append(f"the {chosen} translation fit did not converge")
    ho_r = np.abs(ho.residual_px) if ho is not None else np.zeros(0)
    out = replace(
        res,
        status="ok" if best.converged else "warning",
        calibration=apply_theta(base, best.theta),
        values=named(best.theta),
        sigma=sigma,
        correlation={},
        fitted=fitted,
        fixed_unobservable=(),
        iterations=best.iterations + (hold_fit.iterations if hold_fit is not None else 0),
        converged=best.converged,
        train=ErrorStats.of(r[best.inlier]),
        train_all=ErrorStats.of(r),
        holdout=ErrorStats.of(ho_r[ho.inlier] if ho is not None else ho_r),
        holdout_all=ErrorStats.of(ho_r[ho.usable] if ho is not None else ho_r),
        n_outliers=int(np.count_nonzero(~best.inlier)),
        residual_sigma_px=best.rms_px,
        warnings=tuple(warnings),
        tracks=None,
        holdout_fit_values=(
            named(hold_fit.theta) if hold_fit is not None and fitted_on is streaks else None
        ),
    )
    return replace(nat, result=out, translation=info, rotation_only=res, sigma=sigma_info)
