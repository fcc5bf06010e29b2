"""MAP fit of the gyro scale of natural-scene fits: the six scale / cross-axis entries fitted
under a Gaussian prior, the reported sigma the posterior's.

A natural fit (:func:`calib.natural.pipeline.calibrate_natural`) leaves the gyro's symmetric scale
error ``S`` (:mod:`calib.params`) unfitted: a few hundred inter-frame rotations of hand shake
determine it only about as well as a factory trim does (``fx`` follows the scale of the gyro
axis along camera y almost one to one; only the field of view's nonlinearity and roll
separate them). Left at the identity, a 0.3 % entry moves ``fx`` by 0.3 % and the rotation by
a tenth of a degree; fitted freely, the data's own noise moves it by as much. Between the two,
the maximum a posteriori fit

    minimise  Σ pseudo-Huber(|r_i|)  +  ½ s² Σ_k (S_k − S0_k)² / σ_k²

over every fitted parameter and ``S`` (``s``: the data's per-coordinate residual sigma, held
fixed, so the prior rows weigh as many pixels as ``σ_k`` is worth; ``S0``: the session's
guess, the identity) lets the data move ``S`` where they can and holds it at the prior
otherwise. ``σ_k`` is :data:`calib.natural.sigma.GYRO_SCALE_SIGMA` for a diagonal entry and
``1/√2`` of it off the diagonal (an off-diagonal entry of ``S`` averages two independent
matrix entries). A scale matrix given in session.yaml counts as known and is not fitted
(:func:`scale_is_known`); ``--fit ...,scale`` fits it freely (no prior).

Sigma: the posterior covariance ``s² H⁻¹`` (``H = A + s² Λ``, ``A = JᵀWJ`` of the data, ``Λ``
the prior precision) and three sandwiches with the prior's own ``s² Λ`` in the meat, the
largest per parameter: clustered by frame pair and by blocks of
:data:`calib.natural.sigma.BLOCK_PAIRS` pairs (:mod:`calib.natural.sigma`), and by scene cell
(:mod:`calib.natural.scene`: the tracks of one part of the scene over the whole session, whose
shared tracking error the other two cannot see). This replaces the consider term (the
unfitted scale's spread carried into the other parameters): the prior now enters the estimate
itself. The prior rows enter no residual statistic: train / hold-out errors and the residual
sigma are of the data alone, and the hold-out is that of a MAP fit on the training frames.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from calib.data import StreakSet, holdout_mask, relative_gyro
from calib.errors import CalibError
from calib.fitcore import FINE_DELTA_SIGMAS, FitOptions, outlier_threshold, rayleigh_sigma
from calib.grid import GridEvaluator
from calib.natural.scene import SCENE_CELL_PX, SCENE_MIN_CELLS, cluster_meat, scene_cells
from calib.natural.sigma import BLOCK_PAIRS, GYRO_SCALE_SIGMA, SCALE_NAMES, gyro_scale_known
from calib.params import LAYOUT, THETA_NAMES, apply_theta
from calib.result import CalibResult, ErrorStats, named, sigma_block
from calib.solve import huber_weights, lm_driver, pseudo_huber
from calib.uncertainty import MODEL_FLOOR_PX, information

#: How a natural fit treats the unfitted gyro scale: ``map`` (this module) or ``consider``
#: (left at the session's guess, its spread added to the sigma: :mod:`calib.natural.sigma`).
SCALE_PRIORS = ("map", "consider")
DEFAULT_SCALE_PRIOR = "map"
#: Most Levenberg–Marquardt iterations of one MAP fit (it starts at the data's optimum with
#: the scale fixed, one or two Gauss–Newton steps away).
MAP_MAX_ITER = 10
#: The fit's own warning that a MAP fit answers (:func:`calib.fitcore.scale_check`).
_SCALE_WARNING = "the gyro shows a scale/cross-axis error that is not fitted"


def scale_is_known(res: CalibResult) -> bool:
    """Whether session.yaml gave the gyro scale matrix (anything but the identity)."""
    return gyro_scale_known(res.initial)


def prior_sigma(name: str, sigma: float = GYRO_SCALE_SIGMA) -> float:
    """Prior 1-sigma of scale entry ``name`` (``scale_xy``: an average of two entries).

    >>> prior_sigma("scale_xx", 0.004), round(prior_sigma("scale_xy", 0.004), 6)
    (0.004, 0.002828)
    """
    return float(sigma if name[-2] == name[-1] else sigma / np.sqrt(2.0))


@dataclass(frozen=True)
class MapFit:
    """One MAP fit: the estimate, its posterior sigma and what went into them."""

    theta: np.ndarray
    names: tuple[str, ...]
    sigma: np.ndarray
    correlation: np.ndarray
    #: Per parameter: the posterior ``s² H⁻¹``, the frame, block (and scene) sandwiches.
    parts: dict[str, dict[str, float]]
    iterations: int
    converged: bool
    #: Data residual sigma (px per coordinate) and the outlier threshold (px) of the fit.
    residual_sigma_px: float
    threshold_px: float
    #: ``Σ (S_k − S0_k)² / σ_k²`` at the estimate (the prior rows' share of the cost / s²·2).
    prior_chi2: float


def map_fit(
    ev: GridEvaluator,
    streaks: StreakSet,
    theta0: np.ndarray,
    names: tuple[str, ...],
    sigma_prior: float = GYRO_SCALE_SIGMA,
    max_iter: int = MAP_MAX_ITER,
    scene: np.ndarray | None = None,
) -> MapFit:
    """The MAP fit of the module docstring over ``names`` (the scale entries among them get
    the prior, centred on their ``theta0`` values), from ``theta0``. ``scene``: ``(N,)``
    scene-cell cluster of each streak (:mod:`calib.natural.scene`), a third sandwich where
    the inliers span at least :data:`calib.natural.scene.SCENE_MIN_CELLS` cells.

    The inliers are those within the fit's outlier threshold (:func:`outlier_threshold`,
    from the errors at ``theta0``); the robust loss is the final stage's pseudo-Huber."""
    if sigma_prior <= 0:
        raise CalibError(f"gyro scale prior sigma must be positive, got {sigma_prior}")
    free = tuple(LAYOUT[n] for n in names)
    fr = list(free)
    theta0 = np.asarray(theta0, float)
    rho0 = np.linalg.norm(ev.residual(theta0, streaks)[:, :2], axis=1)
    inl = rho0 <= outlier_threshold(rho0)
    thr = outlier_threshold(rho0[inl])
    inl = rho0 <= thr
    fitset = streaks.subset(inl)
    sig = max(rayleigh_sigma(rho0[inl]), MODEL_FLOOR_PX)
    delta = max(FINE_DELTA_SIGMAS * sig, 1e-3)
    r0 = ev.residual(theta0, fitset)[:, :2]
    w0 = huber_weights(np.linalg.norm(r0, axis=1), delta)
    s2 = max(float(np.sum(w0[:, None] * r0**2) / max(r0.size - len(fr), 1)), MODEL_FLOOR_PX**2)
    prec = np.array(
        [1.0 / prior_sigma(n, sigma_prior) ** 2 if n in SCALE_NAMES else 0.0 for n in names]
    )
    lam = s2 * prec  # prior rows in the data cost's units (px²)
    mu = theta0[fr].copy()

    def prior_cost(theta: np.ndarray) -> float:
        return 0.5 * float(np.sum(lam * (theta[fr] - mu) ** 2))

    def cost_of(r: np.ndarray) -> float:
        return float(np.sum(pseudo_huber(np.linalg.norm(r, axis=1), delta)))

    def linearise(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        r, J = ev.evaluate(theta, fitset, free)
        w = huber_weights(np.linalg.norm(r, axis=1), delta)
        A = information(J, w, free) + np.diag(lam)
        g = (J[:, :, fr] * w[:, None, None]).reshape(-1, len(fr)).T @ r.reshape(-1)
        return A, g + lam * (theta[fr] - mu), cost_of(r) + prior_cost(theta)

    def trial_cost(theta: np.ndarray) -> float:
        return cost_of(ev.residual(theta, fitset)) + prior_cost(theta)

    res = lm_driver(theta0, free, linearise, trial_cost, max(0.1 * sig, 1e-5), max_iter, lam0=1e-6)
    theta = res.theta
    r, J = ev.evaluate(theta, fitset, free)
    r, J = r[:, :2], J[:, :2, :][:, :, fr]
    w = huber_weights(np.linalg.norm(r, axis=1), delta)
    H = information(J, w, tuple(range(len(fr)))) + np.diag(lam)
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hinv = np.linalg.pinv(H / np.outer(d, d)) / np.outer(d, d)
    post = s2 * Hinv
    prior_meat = np.diag(s2 * lam)
    frames = np.asarray(fitset.frame)
    var = {
        "posterior": np.diag(post),
        "frame": np.diag(Hinv @ (cluster_meat(J, r, w, frames) + prior_meat) @ Hinv),
        "block": np.diag(Hinv @ (cluster_meat(J, r, w, frames // BLOCK_PAIRS) + prior_meat) @ Hinv),
    }
    cells = None if scene is None else np.asarray(scene)[inl]
    if cells is not None and np.unique(cells).size >= SCENE_MIN_CELLS:
        var["scene"] = np.diag(Hinv @ (cluster_meat(J, r, w, cells) + prior_meat) @ Hinv)
    sd = {k: np.sqrt(np.maximum(v, 0.0)) for k, v in var.items()}
    sigma = np.max(np.stack(list(sd.values())), axis=0)
    sp = np.sqrt(np.maximum(np.diag(post), 1e-300))
    corr = post / np.outer(sp, sp)
    parts = {n: {k: float(v[i]) for k, v in sd.items()} for i, n in enumerate(names)}
    chi2 = float(np.sum(prec * (theta[fr] - mu) ** 2))
    rs = float(np.sqrt(s2))
    return MapFit(theta, names, sigma, corr, parts, res.iterations, res.converged, rs, thr, chi2)


def _stats(ev: GridEvaluator, theta: np.ndarray, streaks: StreakSet, thr: float):
    rho = np.linalg.norm(ev.residual(theta, streaks)[:, :2], axis=1)
    return ErrorStats.of(rho[rho <= thr]), ErrorStats.of(rho), int(np.count_nonzero(rho > thr))


def with_scale_prior(
    res: CalibResult,
    streaks: StreakSet,
    gyro: GyroTrace,
    options: FitOptions,
    sigma_prior: float = GYRO_SCALE_SIGMA,
) -> tuple[CalibResult, dict[str, Any]]:
    """``res`` (a natural fit with the gyro scale unfitted and unknown) refitted as the MAP
    fit of the module docstring: values, calibration, sigma, correlation, residual and
    hold-out statistics replaced (data residuals only), and what went into the sigma."""
    if any(n in res.fitted for n in SCALE_NAMES) or scale_is_known(res):
        raise CalibError("the MAP scale fit applies to fits that leave an unknown scale unfitted")
    base = res.initial
    cam = base.camera
    g = relative_gyro(gyro.upsampled(options.gyro_upsample), streaks.t0_s)
    ev = GridEvaluator(g, base.R_cam_imu, cam.dist, cam.height)
    names = tuple(n for n in res.fitted if n in res.sigma) + SCALE_NAMES
    holdout, holdout_all = res.holdout, res.holdout_all
    held = holdout_mask(np.asarray(streaks.frame), options.holdout_fraction)
    train_set, test = streaks.subset(~held), streaks.subset(held)
    theta0 = np.array([res.values[n] for n in THETA_NAMES], float)
    cells = scene_cells(streaks, relative_gyro(gyro, streaks.t0_s), apply_theta(base, theta0))
    train_fit = None
    if res.holdout_fit_values is not None and len(test):
        # calibrate's order: a fit on the training frames for the hold-out, then all frames
        th_train = np.array([res.holdout_fit_values[n] for n in THETA_NAMES], float)
        train_fit = map_fit(ev, train_set, th_train, names, sigma_prior, scene=cells[~held])
        holdout, holdout_all, _ = _stats(ev, train_fit.theta, test, train_fit.threshold_px)
        fitted_on, on = streaks, np.ones(len(streaks), bool)
    else:
        fitted_on, on = train_set, ~held
    fit = map_fit(ev, fitted_on, theta0, names, sigma_prior, scene=cells[on])
    if train_fit is None and len(test):
        holdout, holdout_all, _ = _stats(ev, fit.theta, test, fit.threshold_px)
    train, train_all, n_out = _stats(ev, fit.theta, fitted_on, fit.threshold_px)
    sigma = {n: float(s) for n, s in zip(names, fit.sigma, strict=True)}
    corr = {
        a: {b: float(fit.correlation[i, j]) for j, b in enumerate(names)}
        for i, a in enumerate(names)
    }
    warnings = tuple(w for w in res.warnings if not w.startswith(_SCALE_WARNING))
    if not fit.converged:
        warnings += ("the MAP gyro-scale fit did not converge within its iteration limit",)
    calib = apply_theta(base, fit.theta).with_(sigma=sigma_block(sigma))
    out = replace(
        res,
        status="failed" if not fit.converged else ("warning" if warnings else "ok"),
        calibration=calib,
        values=named(fit.theta),
        sigma=sigma,
        correlation=corr,
        fitted=names,
        iterations=res.iterations + fit.iterations,
        converged=res.converged and fit.converged,
        train=train,
        train_all=train_all,
        holdout=holdout,
        holdout_all=holdout_all,
        n_outliers=n_out,
        residual_sigma_px=fit.residual_sigma_px,
        warnings=warnings,
        holdout_fit_values=None if train_fit is None else named(train_fit.theta),
    )
    info = {
        "gyro_scale": "map",
        "gyro_scale_sigma": sigma_prior,
        "gyro_scale_prior_chi2": fit.prior_chi2,
        "block_pairs": BLOCK_PAIRS,
        "scene_cell_px": SCENE_CELL_PX,
        "scene_cells": int(np.unique(cells).size),
        "scene_min_cells": SCENE_MIN_CELLS,
        "parts": fit.parts,
        "moved": {n: out.values[n] - res.values[n] for n in sigma},
    }
    return out, info


def check_scale_prior(scale_prior: str) -> None:
    """Refuse an unknown ``scale_prior`` (one line naming the choices)."""
    if scale_prior not in SCALE_PRIORS:
        raise CalibError(f"gyro scale prior must be one of {SCALE_PRIORS}, got {scale_prior!r}")


def natural_sigma_fit(
    res: CalibResult,
    streaks: StreakSet,
    gyro: GyroTrace,
    options: FitOptions,
    scale_prior: str = DEFAULT_SCALE_PRIOR,
) -> tuple[CalibResult, dict[str, Any]]:
    """The natural fit's last step: the MAP scale fit (:func:`with_scale_prior`) when
    ``scale_prior`` is ``map`` and the scale is unknown and unfitted; otherwise the fit kept
    and its sigma widened by :func:`calib.natural.sigma.honest_sigma` (the consider term
    for an unknown unfitted scale, none for a known or freely fitted one). The calibration's
    sigma block is the returned sigma either way."""
    from calib.natural.sigma import honest_sigma

    check_scale_prior(scale_prior)
    fitted = any(n in res.fitted for n in SCALE_NAMES)
    known = scale_is_known(res)
    if scale_prior == "map" and not fitted and not known:
        return with_scale_prior(res, streaks, gyro, options)
    sigma, info = honest_sigma(res, streaks, gyro, options)
    info["gyro_scale"] = "fitted" if fitted else ("known" if known else "consider")
    calib = res.calibration.with_(sigma=sigma_block(sigma))
    return replace(res, sigma=sigma, calibration=calib), info
