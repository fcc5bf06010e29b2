"""The last stages of one calibration fit (:func:`calib.fit._fit`): the optional
frame-noise GLS refinement, then uncertainty, warnings, hold-out statistics, status and the
:class:`calib.result.CalibResult`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.kernels import constant_mat3, omega_cam_fn
from calib import init as init_mod
from calib import uncertainty
from calib.errors import CalibError
from calib.fitcore import (
    MAX_RESIDUAL_SIGMA_PX,
    MIN_INLIER_FRACTION,
    MIN_OUTLIER_PX,
    MIN_STREAKS,
    OUTLIER_SIGMAS,
    rayleigh_sigma,
    reorient,
    scale_check,
)
from calib.params import LAYOUT, THETA_NAMES, apply_theta
from calib.result import CalibResult, ErrorStats, named, sigma_block
from calib.stages import Coarse, Fine, Mode, Prepared, final_track_errors


@dataclass(frozen=True)
class Gls:
    """The frame-noise GLS refinement (:mod:`calib.framenoise`); ``theta`` None: skipped."""

    theta: np.ndarray | None
    iterations: int = 0
    converged: bool = True
    sigma: np.ndarray | None = None
    correlation: np.ndarray | None = None
    timings: tuple[tuple[str, float], ...] = ()
    warnings: tuple[str, ...] = ()


def frame_noise_fit(prep: Prepared, co: Coarse, md: Mode, fine: Fine) -> Gls:
    """GLS refinement under the frame-correlated gyro-noise model after the robust fit."""
    from calib.framenoise import gls_refine

    lm = fine.lm
    try:
        gls = gls_refine(
            md.ev_fine,
            fine.train.subset(fine.inl),
            fine.theta,
            co.free,
            lm.weights,
            prep.initial.camera.height,
            float(fine.theta[LAYOUT["readout_s"]]),
            start=(lm.residual, lm.jacobian),
        )
    except CalibError as exc:
        return Gls(
            None,
            warnings=(
                f"frame-noise refinement skipped ({exc}); the estimate is the plain robust fit",
            ),
        )
    sc = np.sqrt(np.maximum(np.diag(gls.covariance), 1e-300))
    return Gls(
        gls.theta,
        gls.iterations,
        gls.converged,
        gls.sigma,
        gls.covariance / np.outer(sc, sc),
        (("gls_iterations", gls.iterations), ("gls_prior_scale", gls.prior_scale)),
    )


def assemble(
    prep: Prepared,
    ini: init_mod.InitResult,
    co: Coarse,
    md: Mode,
    fine: Fine,
    gls: Gls | None,
    timings: dict[str, float],
    clock: Callable[[], float],
    t_start: float,
) -> CalibResult:
    """Uncertainty, warnings, hold-out statistics, status and the :class:`CalibResult`;
    ``timings`` gets the GLS entries and ``total`` (``clock() - t_start``)."""
    model, train, free, lm, cam = md.model, fine.train, co.free, fine.lm, prep.initial.camera
    warnings = [*prep.warnings, *co.warnings, *md.warnings]
    theta, iters, converged = fine.theta, fine.iterations, fine.converged
    rho = fine.rho
    sig = rayleigh_sigma(rho[fine.inl])
    thr = max(OUTLIER_SIGMAS * sig, MIN_OUTLIER_PX)
    out = rho > thr
    unc = uncertainty.estimate(lm.jacobian, lm.residual, lm.weights, fine.fitset.frame, free)
    sigma_vec, corr_mat = unc.sigma, unc.correlation
    if gls is not None:
        warnings.extend(gls.warnings)
        if gls.theta is not None:
            assert gls.sigma is not None and gls.correlation is not None
            theta, iters = gls.theta, iters + gls.iterations
            converged = converged and gls.converged
            sigma_vec, corr_mat = gls.sigma, gls.correlation
            timings.update(gls.timings)
            rho = np.linalg.norm(model.residual_np(theta, train), axis=1)
            out = rho > thr
    warnings.extend(unc.warnings)
    warnings.extend(scale_check(md.ev_fine, theta, fine.fitset, lm.weights, free))
    t_mid = train.frame_t_s + cam.readout_s / 2 + train.exposure_s / 2
    R = apply_theta(prep.initial, theta).R_cam_imu
    w_cam = np.stack(
        omega_cam_fn(
            prep.g.omega_components,
            constant_mat3(R),
            tuple(theta[LAYOUT["bias"]]),
            theta[LAYOUT["timeshift_s"]],
        )(t_mid),
        axis=1,
    )
    warnings.extend(uncertainty.excitation_warnings(w_cam))

    if len(prep.test):
        _, rho_t, _ = reorient(model, theta, prep.test, thr)
        out_t = rho_t > thr
        holdout, holdout_all = ErrorStats.of(rho_t[~out_t]), ErrorStats.of(rho_t)
    else:
        holdout = holdout_all = ErrorStats.of(np.zeros(0))
    n_in = int(np.count_nonzero(~out))
    status = "ok"
    if n_in < MIN_INLIER_FRACTION * len(train):
        warnings.append(
            f"only {n_in} of {len(train)} streaks agree with the model: the data "
            f"contradict it (wrong session, gyro or initial rotation?)"
        )
        status = "failed"
    if fine.n_agree is not None:
        warnings.append(
            f"only {fine.n_agree} streaks agree with the model (need {MIN_STREAKS}): the "
            f"data contradict it"
        )
        status = "failed"
    if sig > MAX_RESIDUAL_SIGMA_PX:
        warnings.append(
            f"endpoint residuals are large (robust sigma {sig:.2f} px): the data "
            f"contradict the model"
        )
        status = "failed"
    if not converged:
        warnings.append("the solver did not converge within its iteration limit")
        status = "failed"
    if status == "ok" and warnings:
        status = "warning"
    track_stats: dict = {"residuals": md.mode}
    if md.tracks is not None:
        rho_tr = final_track_errors(md, theta, md.tracks)
        track_stats.update(
            tracks=ErrorStats.of(rho_tr[fine.tinl]),
            n_tracks=len(md.tracks),
            n_track_outliers=int(np.count_nonzero(~fine.tinl)),
        )
    sigma = named(sigma_vec, free)
    calib = apply_theta(prep.initial, theta).with_(sigma=sigma_block(sigma))
    corr = {
        THETA_NAMES[a]: {THETA_NAMES[b]: float(corr_mat[i, j]) for j, b in enumerate(free)}
        for i, a in enumerate(free)
    }
    timings["total"] = clock() - t_start
    return CalibResult(
        status=status,
        calibration=calib,
        initial=prep.initial,
        values=named(theta),
        sigma=sigma,
        correlation=corr,
        fitted=tuple(THETA_NAMES[i] for i in free),
        fixed_unobservable=tuple(THETA_NAMES[i] for i in co.dropped),
        iterations=iters,
        converged=converged,
        train=ErrorStats.of(rho[~out]),
        train_all=ErrorStats.of(rho),
        holdout=holdout,
        holdout_all=holdout_all,
        n_outliers=int(np.count_nonzero(out)),
        n_flipped=int(np.count_nonzero(fine.reoriented)),
        residual_sigma_px=sig,
        init_shift_curve=ini.shift_curve,
        warnings=tuple(warnings),
        timings_s=timings,
        **track_stats,
    )
