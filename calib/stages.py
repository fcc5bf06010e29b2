"""The stages of one calibration fit (:func:`calib.fit._fit`), each a function with a typed
result that the next stage takes: input preparation, initialisation, coarse LM, residual
mode and tracks, fine robust rounds, optional frame-noise GLS, statistics and result."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from calib import init as init_mod
from calib import uncertainty
from calib.centreline import CentreGridEvaluator
from calib.data import StreakSet, covered_mask, holdout_mask, relative_gyro
from calib.errors import CalibError
from calib.fitcore import (
    FINE_DELTA_SIGMAS,
    MIN_FRAMES,
    MIN_STREAKS,
    MIN_TRACK_SHARE,
    SUBSAMPLE,
    FitOptions,
    Progress,
    ProgressFn,
    check_fit_inputs,
    outlier_threshold,
    rayleigh_sigma,
    reorient,
)
from calib.grid import GridEvaluator
from calib.params import GROUPS, LAYOUT, THETA_NAMES, symmetric_scale_form, theta_from
from calib.problem import ResidualModel, choose_substeps
from calib.solve import LMResult, levenberg_marquardt
from calib.tracks import build_tracks, concat


@dataclass(frozen=True)
class Reporter:
    """Progress reports of one fit, timed from ``t0``."""

    progress: ProgressFn | None
    clock: Callable[[], float]
    t0: float

    def report(self, stage: str) -> Callable[[int, float], None] | None:
        progress = self.progress
        if progress is None:
            return None
        return lambda it, cost: progress(Progress(stage, it, cost, self.clock() - self.t0))

    def start(self, stage: str) -> None:
        if self.progress is not None:
            self.progress(Progress(stage, 0, float("nan"), self.clock() - self.t0))


@dataclass(frozen=True)
class Prepared:
    """Checked input: covered streaks, the hold-out split and the residual models."""

    free: tuple[int, ...]
    initial: Calibration
    g: GyroTrace
    streaks: StreakSet
    train: StreakSet
    test: StreakSet
    theta0: np.ndarray
    readout_bound: float
    model: ResidualModel
    #: The grid evaluator of the search, the coarse stages and the final stage.
    ev: GridEvaluator
    warnings: tuple[str, ...]


def prepare(
    streaks: StreakSet, gyro: GyroTrace, initial: Calibration, options: FitOptions
) -> Prepared:
    """Input checks (coverage, motion), the hold-out split and the residual models."""
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
    readout_bound = max(2 * cam.readout_s, 0.05)
    model = ResidualModel(
        g, initial.R_cam_imu, cam.dist, cam.height,
        choose_substeps(train, cam.height, readout_bound),
    )  # fmt: skip
    ev = GridEvaluator(g, initial.R_cam_imu, cam.dist, cam.height)
    return Prepared(
        free, initial, g, streaks, train, test, theta_from(initial), readout_bound, model, ev,
        tuple(warnings),
    )  # fmt: skip


def all_frames(prep: Prepared) -> Prepared:
    """The same prepared input with every frame for training and none held out (the refit
    of :func:`calib.fit.calibrate`; the checks and the gyro are those of ``prep``)."""
    cam = prep.initial.camera
    n_sub = choose_substeps(prep.streaks, cam.height, prep.readout_bound)
    return replace(
        prep,
        train=prep.streaks,
        test=prep.streaks.subset(np.zeros(len(prep.streaks), dtype=bool)),
        model=replace(prep.model, n_sub=n_sub),
    )


def initialise(prep: Prepared, options: FitOptions, rep: Reporter) -> init_mod.InitResult:
    """Shift/focal search (:mod:`calib.init`)."""
    rep.start("initial search")
    return init_mod.initialise(
        prep.ev,
        prep.train,
        prep.theta0,
        LAYOUT["timeshift_s"] in prep.free,
        LAYOUT["fx"] in prep.free or LAYOUT["fy"] in prep.free,
        options.shift_window_s,
    )


@dataclass(frozen=True)
class Coarse:
    """The coarse estimate, the parameters left free and those held as unobservable."""

    theta: np.ndarray
    free: tuple[int, ...]
    dropped: list[int]
    iterations: int
    ev: GridEvaluator
    warnings: tuple[str, ...]


def coarse_fit(
    prep: Prepared, ini: init_mod.InitResult, options: FitOptions, rep: Reporter
) -> Coarse:
    """Robust LM on a subsample: shift and focal first, then every observable parameter."""
    warnings: list[str] = []
    theta, free, train = ini.theta, prep.free, prep.train
    rng = np.random.default_rng(options.seed)
    sub_idx = np.arange(len(train))
    if sub_idx.size > SUBSAMPLE:
        sub_idx = np.sort(rng.choice(sub_idx, SUBSAMPLE, replace=False))
    sub = train.subset(sub_idx)
    iters = 0
    ev = prep.ev
    stage1 = tuple(i for i in free if i in GROUPS["timeshift"] + GROUPS["fx"] + GROUPS["fy"])
    delta = max(2.0 * ini.median_error_px, 0.5)
    rep.start("coarse")
    if stage1:
        lm = levenberg_marquardt(
            ev, sub, theta, stage1, delta, 15, 0.05, progress=rep.report("coarse: shift, focal")
        )
        theta, iters = lm.theta, iters + lm.iterations
    lm = levenberg_marquardt(ev, sub, theta, free, delta, 20, 0.02, progress=rep.report("coarse"))
    theta, iters = lm.theta, iters + lm.iterations
    info = uncertainty.information(lm.jacobian, lm.weights, free)
    dropped = uncertainty.unobservable(info, free)
    if dropped:
        names = [THETA_NAMES[i] for i in dropped]
        warnings.append(
            f"not observable from this motion, kept at the initial value: {', '.join(names)}"
        )
        theta[dropped] = prep.theta0[dropped]
        free = tuple(i for i in free if i not in dropped)
        lm = levenberg_marquardt(
            ev, sub, theta, free, delta, 20, 0.02, progress=rep.report("coarse")
        )
        theta, iters = lm.theta, iters + lm.iterations
    return Coarse(theta, free, dropped, iters, ev, tuple(warnings))


@dataclass(frozen=True)
class Mode:
    """The final stage's residuals, its tracks, model and evaluator."""

    mode: str
    use_ep: bool
    tracks: StreakSet | None
    model: ResidualModel
    ev_fine: GridEvaluator
    warnings: tuple[str, ...]


def choose_mode(
    prep: Prepared, co: Coarse, options: FitOptions, reuse: GridEvaluator | None = None
) -> Mode:
    """Resolve ``FitOptions.residuals`` and build the inter-frame tracks it asks for;
    ``reuse``: the final stage's evaluator of an earlier fit (a refit: its CasADi functions
    are built already)."""
    warnings: list[str] = []
    train, cam, model = prep.train, prep.initial.camera, prep.model
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
        tracks, _ = build_tracks(co.ev, co.theta, train)
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
            prep.g, prep.initial.R_cam_imu, cam.dist, cam.height,
            choose_substeps(both, cam.height, prep.readout_bound),
        )  # fmt: skip
    ev_fine: GridEvaluator = co.ev if reuse is None else reuse
    if reuse is None and options.centreline and prep.streaks.centre is not None:
        cam = prep.initial.camera
        ev_fine = CentreGridEvaluator(
            prep.g, prep.initial.R_cam_imu, cam.dist, cam.height, model.n_sub,
            prep.streaks.centre.shape[1],
        )  # fmt: skip
    return Mode(mode, use_ep, tracks, model, ev_fine, tuple(warnings))


@dataclass(frozen=True)
class Fine:
    """The robust fit on every training streak / track after outlier rejection."""

    theta: np.ndarray
    train: StreakSet  # reoriented
    inl: np.ndarray
    tinl: np.ndarray
    reoriented: np.ndarray
    converged: bool
    fitset: StreakSet
    lm: LMResult
    iterations: int
    round_iterations: tuple[int, ...]
    #: Endpoint errors ``(N,)`` of ``train`` at ``theta`` (the per-streak model).
    rho: np.ndarray
    #: The outlier thresholds (px) of the last classification: endpoints, tracks.
    thresholds: tuple[float, float]
    #: Set when fewer than :data:`MIN_STREAKS` streaks agreed with the model (the count): the
    #: last round fitted every streak and the fit has failed.
    n_agree: int | None = None


def final_track_errors(md: Mode, theta: np.ndarray, tracks: StreakSet) -> np.ndarray:
    """Track errors ``(N,)`` (px) by the final stage's evaluator (grid: far cheaper than the
    per-streak model over a frame period, and the more accurate)."""
    return np.linalg.norm(md.ev_fine.residual(theta, tracks)[:, :2], axis=1)


def fine_fit(
    prep: Prepared,
    co: Coarse,
    md: Mode,
    options: FitOptions,
    rep: Reporter,
    warm: tuple[float, float] | None = None,
) -> Fine:
    """Up to three robust LM rounds with outlier rejection and reorientation in between.

    ``warm``: a refit (:func:`calib.fit.calibrate`) from a converged fit's ``co.theta`` with
    that fit's outlier thresholds ``(endpoints, tracks)`` for the first classification (a
    cold fit derives them from every streak at the coarse estimate)."""
    theta, iters, free, model, use_ep, tracks = (
        co.theta, co.iterations, co.free, md.model, md.use_ep, md.tracks
    )  # fmt: skip
    train = prep.train
    inl = np.ones(len(train), dtype=bool)
    tinl = np.ones(0 if tracks is None else len(tracks), dtype=bool)
    reoriented = np.zeros(len(train), dtype=bool)
    converged = settled = False
    fitset = train
    rounds: list[int] = []
    lm: LMResult | None = None
    rho = np.zeros(0)
    thr = thr_t = float("nan")
    n_agree: int | None = None
    for round_ in range(3):
        changed = 0
        new_inl = inl
        if use_ep:
            rho = np.linalg.norm(model.residual_np(theta, train), axis=1)
            thr = warm[0] if warm is not None and round_ == 0 else outlier_threshold(rho[inl])
            train, rho, flip = reorient(model, theta, train, thr, rho)
            reoriented ^= flip
            new_inl = rho <= thr
            changed += int(np.count_nonzero(new_inl != inl))
        new_tinl = tinl
        if tracks is not None:
            rho_t = final_track_errors(md, theta, tracks)
            thr_t = warm[1] if warm is not None and round_ == 0 else outlier_threshold(rho_t[tinl])
            new_tinl = rho_t <= thr_t
            changed += int(np.count_nonzero(new_tinl != tinl))
        if round_ and changed <= 0.002 * (len(train) * use_ep + tinl.size):
            settled = True
            break  # the inlier sets have settled
        inl, tinl = new_inl, new_tinl
        if use_ep and np.count_nonzero(inl) < MIN_STREAKS:
            # Too few streaks agree to fit: a fit quality, not an input error. One last round
            # over every streak gives the summary an estimate; the status says failed.
            n_agree = int(np.count_nonzero(inl))
            inl = np.ones(len(train), dtype=bool)
        parts, errors = [], []
        if use_ep:
            parts.append(train.subset(inl))
            errors.append(rho[inl])
        if tracks is not None:
            parts.append(tracks.subset(tinl))
            errors.append(rho_t[tinl])
        fitset = parts[0] if len(parts) == 1 else concat(parts)
        sig_fit = rayleigh_sigma(np.concatenate(errors))
        lm = levenberg_marquardt(
            md.ev_fine,
            fitset,
            theta,
            free,
            max(FINE_DELTA_SIGMAS * sig_fit, 1e-3),
            max_iter=options.max_iter,
            step_tol=max(0.1 * sig_fit, 1e-5),
            lam0=1e-6,
            progress=rep.report(f"{'refit' if warm is not None else 'fine'} round {round_ + 1}"),
        )
        theta, iters, converged = lm.theta, iters + lm.iterations, lm.converged
        rounds.append(lm.iterations)
        if n_agree is not None:
            break
    assert lm is not None  # round 1 always runs
    if not (use_ep and settled):
        # Endpoint errors at the final theta (the loop's are of the previous round's).
        rho = np.linalg.norm(model.residual_np(theta, train), axis=1)
    if not use_ep:
        # Endpoint statistics of the training streaks at the track fit (reorientation too).
        thr = outlier_threshold(rho)
        train, rho, flip = reorient(model, theta, train, thr, rho)
        reoriented ^= flip
        inl = rho <= thr
    return Fine(
        theta, train, inl, tinl, reoriented, converged, fitset, lm, iters, tuple(rounds), rho,
        (thr, thr_t), n_agree,
    )  # fmt: skip
