"""Calibration driver: checks, initialisation, coarse-to-fine robust fit, outliers, hold-out.

Stages (each warm-starts the next):

1. input checks (enough streaks and frames, gyro coverage, motion);
2. shift/focal search (:mod:`calib.init`);
3. robust LM on a subsample with the shift and focal lengths only, then with every requested
   parameter that the motion makes observable (near-null directions of the information matrix
   are fixed at their initial value, with a warning);
4. robust LM on every training streak (endpoint residuals) or inter-frame track
   (:mod:`calib.tracks`; ``FitOptions.residuals``), with outlier rejection in between: those
   whose error exceeds ``OUTLIER_SIGMAS`` robust sigmas are dropped, except streaks that fit
   once start and end are swapped: they are counted as wrongly oriented, swapped and kept;
5. uncertainty, warnings and hold-out statistics.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.geometry.kernels import constant_mat3, omega_cam_fn
from blurtrack.io.calibration import Calibration
from calib import init as init_mod
from calib import uncertainty
from calib.data import StreakSet, covered_mask, holdout_mask, relative_gyro
from calib.errors import CalibError
from calib.grid import GridEvaluator
from calib.params import (
    DEFAULT_FIT,
    GROUPS,
    LAYOUT,
    THETA_NAMES,
    apply_theta,
    parse_fit,
    symmetric_scale_form,
    theta_from,
)
from calib.problem import ResidualModel, choose_substeps
from calib.result import CalibResult, ErrorStats, named, sigma_block
from calib.solve import Evaluator, JacobianEvaluator, levenberg_marquardt
from calib.tracks import build_tracks, concat

MIN_STREAKS = 30
MIN_FRAMES = 3
OUTLIER_SIGMAS = 5.0
#: Floor of the outlier threshold (px): detection noise never justifies rejecting less.
MIN_OUTLIER_PX = 0.5
SUBSAMPLE = 2000
#: Integration sub-step of the initialisation and subsample stages (the final stage uses
#: blurtrack.geometry.kernels's default 1 ms).
COARSE_SUBSTEP_S = 3e-3
#: Robust endpoint sigma (px) above which the data are called contradictory.
MAX_RESIDUAL_SIGMA_PX = 3.0
MIN_INLIER_FRACTION = 0.5
#: Score-test threshold (sigmas) of :func:`scale_check`.
SCALE_Z = 3.0
#: Pseudo-Huber scale of the final stage, in robust sigmas: outliers are gone by then, and a
#: scale near the rejection threshold keeps the IRLS weights of inliers nearly constant, so
#: Gauss–Newton converges in two or three Jacobians.
FINE_DELTA_SIGMAS = 5.0
RESIDUALS = ("auto", "endpoints", "tracks", "both")
#: ``auto`` warns when the tracks number less than this share of the training streaks (most
#: of the streaks then go unused). It still fits the tracks alone: on the ``hard`` preset
#: (about 8 % of the streaks pair up) endpoints, alone or with the tracks, put the gyro bias
#: 4–7e-3 rad/s off at z up to 13, the tracks alone 1.3–1.5e-3 rad/s.
MIN_TRACK_SHARE = 0.25


@dataclass(frozen=True)
class FitOptions:
    fit: str = DEFAULT_FIT
    holdout_fraction: float = 0.2
    shift_window_s: float = 0.06
    max_iter: int = 30
    seed: int = 0
    #: Cubic-spline upsampling of the gyro before linear interpolation: the blur model's
    #: (:data:`blurtrack.geometry.gyro.GYRO_UPSAMPLE`); another value fits a model that prediction
    #: and
    #: synthesis do not use, so it is for experiments only.
    gyro_upsample: int = GYRO_UPSAMPLE
    #: Centre-line residuals (:mod:`calib.centreline`) in the final stage; the streaks must
    #: carry centre points (``streaks_from_table(..., centre_k=CENTRE_POINTS)``).
    centreline: bool = False
    #: Generalised-least-squares refinement under the frame-correlated gyro-noise model
    #: (:mod:`calib.framenoise`) after the robust fit.
    frame_noise: bool = False
    #: What the final stage fits: ``endpoints`` (each streak's end predicted from its start),
    #: ``tracks`` (each dot's time midpoint carried to the next frame, :mod:`calib.tracks`;
    #: insensitive to biased streak ends), ``both``, or ``auto``: tracks when the streaks
    #: carry midpoints and at least 30 tracks pair up, else endpoints (a warning says why; it
    #: also warns when tracks are under :data:`MIN_TRACK_SHARE` of the streaks). The result's
    #: ``residuals`` names the choice. Initialisation always uses endpoints.
    residuals: str = "auto"
    #: After the hold-out evaluation, refit on every frame (what is written); see
    #: :func:`calibrate`.
    refit_all: bool = True

    def __post_init__(self) -> None:
        if self.residuals not in RESIDUALS:
            raise CalibError(
                f"residuals must be one of {', '.join(RESIDUALS)}, got {self.residuals!r}"
            )
        if self.residuals in ("tracks", "both") and (self.centreline or self.frame_noise):
            raise CalibError(
                "centre-line residuals and the frame-noise refinement work on "
                "endpoint residuals only (--residuals endpoints)"
            )


def _rayleigh_sigma(rho: np.ndarray) -> float:
    """Per-coordinate sigma from the median 2-D error (Rayleigh median = 1.1774 sigma)."""
    return float(np.median(rho) / 1.1774) if rho.size else 0.0


def _outlier_threshold(rho_inliers: np.ndarray) -> float:
    """Rejection threshold (px) from the current inliers' errors."""
    return max(OUTLIER_SIGMAS * _rayleigh_sigma(rho_inliers), MIN_OUTLIER_PX)


def classify(
    model: ResidualModel, theta: np.ndarray, streaks: StreakSet, threshold_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Endpoint errors ``(N,)``, outlier mask and wrongly-oriented mask at ``theta``."""
    rho = np.linalg.norm(model.residual_np(theta, streaks), axis=1)
    out = rho > threshold_px
    flipped = np.zeros_like(out)
    if np.any(out):
        rf = np.linalg.norm(model.residual_np(theta, streaks.subset(out).flipped()), axis=1)
        flipped[np.flatnonzero(out)] = rf <= threshold_px
    return rho, out, flipped


def _reorient(
    model: ResidualModel, theta: np.ndarray, streaks: StreakSet, threshold_px: float
) -> tuple[StreakSet, np.ndarray, np.ndarray]:
    """Swap start and end of the streaks that only fit reversed (orientation resolved wrongly
    by detection). Returns the corrected set, its endpoint errors and the swapped mask."""
    _, _, flip = classify(model, theta, streaks, threshold_px)
    if np.any(flip):
        streaks = streaks.reoriented(flip)
    rho = np.linalg.norm(model.residual_np(theta, streaks), axis=1)
    return streaks, rho, flip


def scale_check(
    ev: Evaluator,
    theta: np.ndarray,
    streaks: StreakSet,
    weights: np.ndarray,
    free: tuple[int, ...],
) -> list[str]:
    """Warn when the data ask for a gyro scale / cross-axis error that is not being fitted.

    One Gauss–Newton step from the optimum with the scale entries freed (the score test):
    an entry that would move by more than :data:`SCALE_Z` of its own (cluster-robust) sigma
    means the fixed scale is wrong and the focal lengths' sigma are optimistic.
    """
    extra = tuple(i for i in GROUPS["scale"] if i not in free)
    if not extra:
        return []
    full = tuple(sorted(free + extra))
    r, J = ev.evaluate(theta, streaks, full)
    A = uncertainty.information(J, weights, full)
    g = np.einsum("n,nki,nk->i", weights, J[:, :, list(full)], r)
    try:
        step = -np.linalg.solve(A, g)
    except np.linalg.LinAlgError:
        return []
    # Sigma under the alternative: residuals after the (linearised) step.
    r_alt = r + np.einsum("nki,i->nk", J[:, :, list(full)], step)
    unc = uncertainty.estimate(J, r_alt, weights, streaks.frame, full)
    z = {THETA_NAMES[i]: step[k] / unc.sigma[k] for k, i in enumerate(full) if i in extra}
    big = {k: v for k, v in z.items() if abs(v) > SCALE_Z}
    if not big:
        return []
    worst = max(big, key=lambda k: abs(big[k]))
    return [
        f"the gyro shows a scale/cross-axis error that is not fitted ({worst} "
        f"{step[full.index(THETA_NAMES.index(worst))]:+.2e}, {abs(big[worst]):.0f} sigma): "
        f"focal lengths and rotation absorb it and their sigma are optimistic; "
        f"refit with --fit ...,scale"
    ]


@dataclass(frozen=True)
class Progress:
    """One progress report of :func:`calibrate`: the stage, its LM iteration (0: the stage
    starts), the cost after it and the seconds since the fit started."""

    stage: str
    iteration: int
    cost: float
    elapsed_s: float


ProgressFn = Callable[[Progress], None]


def check_fit_inputs(streaks: StreakSet, options: FitOptions) -> tuple[int, ...]:
    """Refuse unusable input before any work (raises :class:`CalibError`); returns the parsed
    ``--fit`` groups. ``calibrate`` calls it first; the CLI calls it before the axis search."""
    free = parse_fit(options.fit)
    if options.centreline and streaks.centre is None:
        raise CalibError("centre-line residuals asked for, but the streaks carry no centre lines")
    if len(streaks) < MIN_STREAKS or streaks.n_frames < MIN_FRAMES:
        raise CalibError(
            f"too few streaks to calibrate: {len(streaks)} in {streaks.n_frames} "
            f"frame(s); need at least {MIN_STREAKS} in {MIN_FRAMES} frames"
        )
    return free


def calibrate(
    streaks: StreakSet,
    gyro: GyroTrace,
    initial: Calibration,
    options: FitOptions = FitOptions(),
    clock: Callable[[], float] = time.perf_counter,
    progress: ProgressFn | None = None,
) -> CalibResult:
    """Fit the blur model to measured streak endpoints (see the module docstring).

    With a hold-out (``options.holdout_fraction > 0``) and ``options.refit_all``, the fit on
    the training frames is evaluated on the held-out frames, then refitted on every frame
    from its estimate (the final stage only; the coarse stages and unobservable parameters
    are those of the training fit): the returned calibration, values and sigma are the
    refit's, the hold-out statistics those of the training fit (``holdout_fit_values``).

    Args:
        streaks: measured streaks, times relative to ``streaks.t0_s``.
        gyro: the session's gyro trace on the absolute IMU clock.
        initial: initial guess (the rig's ``session.yaml``); distortion is kept fixed.
        progress: called with a :class:`Progress` at each stage start and LM iteration.
    """
    t_start = clock()
    res = _fit(streaks, gyro, initial, options, clock, progress, None)
    if not (options.refit_all and options.holdout_fraction > 0 and res.status != "failed"):
        return res
    warm = (np.array([res.values[n] for n in THETA_NAMES]), res.fixed_unobservable)
    full = _fit(
        streaks,
        gyro,
        initial,
        replace(options, holdout_fraction=0.0),
        clock,
        progress,
        warm,
        t_start,
    )
    timings = {**res.timings_s, **{f"refit_{k}": v for k, v in full.timings_s.items()}}
    timings["total"] = clock() - t_start
    return replace(
        full,
        holdout=res.holdout,
        holdout_all=res.holdout_all,
        holdout_fit_values=dict(res.values),
        init_shift_curve=res.init_shift_curve,
        iterations=res.iterations + full.iterations,
        warnings=tuple(dict.fromkeys(res.warnings + full.warnings)),
        timings_s=timings,
    )


def _fit(
    streaks: StreakSet,
    gyro: GyroTrace,
    initial: Calibration,
    options: FitOptions,
    clock: Callable[[], float],
    progress: ProgressFn | None,
    warm: tuple[np.ndarray, tuple[str, ...]] | None,
    t_origin: float | None = None,
) -> CalibResult:
    """One fit (:func:`calibrate`); ``warm``: start the final stage at this theta with these
    parameters held (a refit), skipping the search and the coarse stages."""
    t_start = clock()
    t0 = t_start if t_origin is None else t_origin

    def report(stage: str) -> Callable[[int, float], None] | None:
        if progress is None:
            return None
        return lambda it, cost: progress(Progress(stage, it, cost, clock() - t0))

    def start(stage: str) -> None:
        if progress is not None:
            progress(Progress(stage, 0, float("nan"), clock() - t0))

    timings: dict[str, float] = {}
    warnings: list[str] = []
    free = check_fit_inputs(streaks, options)
    initial = symmetric_scale_form(initial)
    cam = initial.camera
    g = relative_gyro(gyro.upsampled(options.gyro_upsample), streaks.t0_s)
    cov = covered_mask(streaks, g, cam, initial.timeshift_cam_imu_s, options.shift_window_s)
    if not np.all(cov):
        bad = np.unique(streaks.frame[~cov])
        if np.count_nonzero(cov) < MIN_STREAKS or np.unique(streaks.frame[cov]).size < MIN_FRAMES:
            raise CalibError(
                f"the gyro does not cover the exposures (± the "
                f"{options.shift_window_s * 1e3:.0f} ms shift search) of "
                f"{bad.size} of {streaks.n_frames} frames; too few remain"
            )
        warnings.append(
            f"{bad.size} frame(s) not covered by the gyro were left out (first: {int(bad[0])})"
        )
        streaks = streaks.subset(cov)
    med_len = float(np.median(streaks.length_px))
    if med_len < 1.0:
        raise CalibError(
            f"no motion: the median streak is {med_len:.2f} px long; the blur "
            f"model cannot be calibrated from static frames"
        )
    held = holdout_mask(streaks.frame, options.holdout_fraction)
    train, test = streaks.subset(~held), streaks.subset(held)
    if len(train) < MIN_STREAKS:
        raise CalibError(f"too few training streaks after the hold-out split ({len(train)})")

    theta0 = theta_from(initial)
    readout_bound = max(2 * cam.readout_s, 0.05)
    model = ResidualModel(
        g,
        initial.R_cam_imu,
        cam.dist,
        cam.height,
        choose_substeps(train, cam.height, readout_bound),
    )
    coarse = ResidualModel(
        g,
        initial.R_cam_imu,
        cam.dist,
        cam.height,
        choose_substeps(train, cam.height, readout_bound, COARSE_SUBSTEP_S),
    )
    start("refit on all frames" if warm else "initial search")
    ini = init_mod.initialise(
        coarse,
        train,
        theta0,
        LAYOUT["timeshift_s"] in free,
        LAYOUT["fx"] in free or LAYOUT["fy"] in free,
        options.shift_window_s,
        search=warm is None,
    )
    theta = ini.theta
    timings["init"] = clock() - t_start

    rng = np.random.default_rng(options.seed)
    sub_idx = np.arange(len(train))
    if sub_idx.size > SUBSAMPLE:
        sub_idx = np.sort(rng.choice(sub_idx, SUBSAMPLE, replace=False))
    sub = train.subset(sub_idx)
    iters = 0
    ev = GridEvaluator(g, initial.R_cam_imu, cam.dist, cam.height)
    stage1 = tuple(i for i in free if i in GROUPS["timeshift"] + GROUPS["fx"] + GROUPS["fy"])
    delta = max(2.0 * ini.median_error_px, 0.5)
    if warm is not None:
        theta = warm[0].copy()
        dropped = [THETA_NAMES.index(n) for n in warm[1]]
        free = tuple(i for i in free if i not in dropped)
    else:
        start("coarse")
        if stage1:
            lm = levenberg_marquardt(
                ev, sub, theta, stage1, delta, 15, 0.05, progress=report("coarse: shift, focal")
            )
            theta, iters = lm.theta, iters + lm.iterations
        lm = levenberg_marquardt(ev, sub, theta, free, delta, 20, 0.02, progress=report("coarse"))
        theta, iters = lm.theta, iters + lm.iterations
        info = uncertainty.information(lm.jacobian, lm.weights, free)
        dropped = uncertainty.unobservable(info, free)
    if dropped and warm is None:
        names = [THETA_NAMES[i] for i in dropped]
        warnings.append(
            f"not observable from this motion, kept at the initial value: {', '.join(names)}"
        )
        theta[dropped] = theta0[dropped]
        free = tuple(i for i in free if i not in dropped)
        lm = levenberg_marquardt(ev, sub, theta, free, delta, 20, 0.02, progress=report("coarse"))
        theta, iters = lm.theta, iters + lm.iterations
    timings["coarse"] = clock() - t_start - timings["init"]

    mode = options.residuals
    if mode == "auto":
        mode = "endpoints"
        if options.centreline or options.frame_noise:
            pass  # both work on endpoint residuals only
        elif train.mid is None:
            warnings.append(
                "the streaks carry no time midpoints (mid_x, mid_y): fitted "
                "endpoints, which a detector's length bias moves"
            )
        else:
            mode = "tracks"
    use_ep = mode in ("endpoints", "both")
    tracks = None
    if mode != "endpoints":
        tracks, _ = build_tracks(model, theta, train)
        if len(tracks) < MIN_STREAKS and options.residuals == "auto":
            warnings.append(
                f"only {len(tracks)} inter-frame tracks paired up (consecutive "
                f"frames must see the same dots): fitted endpoints instead"
            )
            mode, use_ep, tracks = "endpoints", True, None
        elif options.residuals == "auto" and len(tracks) < MIN_TRACK_SHARE * len(train):
            warnings.append(
                f"only {len(tracks)} inter-frame tracks for {len(train)} "
                f"streaks (few dots unflagged in consecutive frames): the fit uses "
                f"the tracks only; --residuals both would use every streak but "
                f"take in the detected ends' biases"
            )
        elif len(tracks) < MIN_STREAKS:
            raise CalibError(
                f"only {len(tracks)} inter-frame tracks found (need "
                f"{MIN_STREAKS}): consecutive frames must see the same dots"
            )
    if tracks is not None:
        both = concat([train, tracks])
        model = ResidualModel(
            g,
            initial.R_cam_imu,
            cam.dist,
            cam.height,
            choose_substeps(both, cam.height, readout_bound),
        )
    ev_fine: GridEvaluator | JacobianEvaluator = ev
    if options.centreline and streaks.centre is not None:
        ev_fine = JacobianEvaluator(model, streaks.centre.shape[1])
    inl = np.ones(len(train), dtype=bool)
    tinl = np.ones(0 if tracks is None else len(tracks), dtype=bool)
    reoriented = np.zeros(len(train), dtype=bool)
    converged = False
    fitset = train
    for round_ in range(3):
        changed = 0
        new_inl = inl
        if use_ep:
            rho, _, _ = classify(model, theta, train, np.inf)
            thr = _outlier_threshold(rho[inl])
            train, rho, flip = _reorient(model, theta, train, thr)
            reoriented ^= flip
            new_inl = rho <= thr
            changed += int(np.count_nonzero(new_inl != inl))
        new_tinl = tinl
        if tracks is not None:
            rho_t = np.linalg.norm(model.residual_np(theta, tracks), axis=1)
            new_tinl = rho_t <= _outlier_threshold(rho_t[tinl])
            changed += int(np.count_nonzero(new_tinl != tinl))
        if round_ and changed <= 0.002 * (len(train) * use_ep + tinl.size):
            break  # the inlier sets have settled
        inl, tinl = new_inl, new_tinl
        if use_ep and np.count_nonzero(inl) < MIN_STREAKS:
            raise CalibError(
                f"only {np.count_nonzero(inl)} streaks agree with the model: the data contradict it"
            )
        parts, errors = [], []
        if use_ep:
            parts.append(train.subset(inl))
            errors.append(rho[inl])
        if tracks is not None:
            parts.append(tracks.subset(tinl))
            errors.append(rho_t[tinl])
        fitset = parts[0] if len(parts) == 1 else concat(parts)
        sig_fit = _rayleigh_sigma(np.concatenate(errors))
        lm = levenberg_marquardt(
            ev_fine,
            fitset,
            theta,
            free,
            max(FINE_DELTA_SIGMAS * sig_fit, 1e-3),
            max_iter=options.max_iter,
            step_tol=max(0.1 * sig_fit, 1e-5),
            lam0=1e-6,
            progress=report(f"{'refit' if warm is not None else 'fine'} round {round_ + 1}"),
        )
        theta, iters, converged = lm.theta, iters + lm.iterations, lm.converged
        timings[f"fine{round_}_iterations"] = lm.iterations
    if not use_ep:
        # Endpoint statistics of the training streaks at the track fit (reorientation too).
        rho, _, _ = classify(model, theta, train, np.inf)
        thr = _outlier_threshold(rho)
        train, rho, flip = _reorient(model, theta, train, thr)
        reoriented ^= flip
        inl = rho <= thr
    timings["fine"] = clock() - t_start - timings["init"] - timings["coarse"]

    rho, _, _ = classify(model, theta, train, np.inf)
    sig = _rayleigh_sigma(rho[inl])
    thr = max(OUTLIER_SIGMAS * sig, MIN_OUTLIER_PX)
    out = rho > thr
    unc = uncertainty.estimate(lm.jacobian, lm.residual, lm.weights, fitset.frame, free)
    sigma_vec, corr_mat = unc.sigma, unc.correlation
    if options.frame_noise:
        from calib.framenoise import gls_refine

        try:
            gls = gls_refine(
                ev_fine,
                train.subset(inl),
                theta,
                free,
                lm.weights,
                cam.height,
                float(theta[LAYOUT["readout_s"]]),
                start=(lm.residual, lm.jacobian),
            )
        except CalibError as exc:
            warnings.append(
                f"frame-noise refinement skipped ({exc}); the estimate is the plain robust fit"
            )
        else:
            theta, iters = gls.theta, iters + gls.iterations
            converged = converged and gls.converged
            sigma_vec = gls.sigma
            sc = np.sqrt(np.maximum(np.diag(gls.covariance), 1e-300))
            corr_mat = gls.covariance / np.outer(sc, sc)
            timings["gls_iterations"] = gls.iterations
            timings["gls_prior_scale"] = gls.prior_scale
            rho, _, _ = classify(model, theta, train, np.inf)
            out = rho > thr
    warnings.extend(unc.warnings)
    warnings.extend(scale_check(ev_fine, theta, fitset, lm.weights, free))
    t_mid = train.frame_t_s + cam.readout_s / 2 + train.exposure_s / 2
    R = apply_theta(initial, theta).R_cam_imu
    w_cam = np.stack(
        omega_cam_fn(
            g.omega_components,
            constant_mat3(R),
            tuple(theta[LAYOUT["bias"]]),
            theta[LAYOUT["timeshift_s"]],
        )(t_mid),
        axis=1,
    )
    warnings.extend(uncertainty.excitation_warnings(w_cam))

    if len(test):
        test, rho_t, _ = _reorient(model, theta, test, thr)
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
    track_stats: dict = {"residuals": mode}
    if tracks is not None:
        rho_t = np.linalg.norm(model.residual_np(theta, tracks), axis=1)
        track_stats.update(
            tracks=ErrorStats.of(rho_t[tinl]),
            n_tracks=len(tracks),
            n_track_outliers=int(np.count_nonzero(~tinl)),
        )
    sigma = named(sigma_vec, free)
    calib = apply_theta(initial, theta)
    calib = calib.with_(sigma=sigma_block(sigma))
    corr = {
        THETA_NAMES[a]: {THETA_NAMES[b]: float(corr_mat[i, j]) for j, b in enumerate(free)}
        for i, a in enumerate(free)
    }
    timings["total"] = clock() - t_start
    return CalibResult(
        status=status,
        calibration=calib,
        initial=initial,
        values=named(theta),
        sigma=sigma,
        correlation=corr,
        fitted=tuple(THETA_NAMES[i] for i in free),
        fixed_unobservable=tuple(THETA_NAMES[i] for i in dropped),
        iterations=iters,
        converged=converged,
        train=ErrorStats.of(rho[~out]),
        train_all=ErrorStats.of(rho),
        holdout=holdout,
        holdout_all=holdout_all,
        n_outliers=int(np.count_nonzero(out)),
        n_flipped=int(np.count_nonzero(reoriented)),
        residual_sigma_px=sig,
        init_shift_curve=ini.shift_curve,
        warnings=tuple(warnings),
        timings_s=timings,
        **track_stats,
    )
