"""The session's calibration error, fitted from the first pass's ``quality_ok`` streaks before
the gyro-template pass uses the blur model.

The initial calibration is nominal (intrinsics, ``R_cam_imu`` and the gyro bias are guesses, the
time shift is the scan's), so every predicted curve is off by a px or two, in the same way for
every frame: one error of the session's seventeen calibration parameters
(:data:`~blurtrack.detect.gyro.calibsteps.CALIBRATION_STEPS`: focal length, principal point,
three axis angles, time offset, readout, three gyro-bias rates, and the gyro's three scale
factors and three cross-axis sensitivities: the symmetric part of its scale matrix ``M``,
:data:`~blurtrack.detect.gyro.calibsteps.SCALE_TERMS`; the antisymmetric part is a turn of the
axes; the parameters' steps and models are :mod:`blurtrack.detect.gyro.calibsteps`). The
image's ``quality_ok`` streaks measure it: their start-to-end vectors ``m`` against the
predicted ``p`` change with the calibration by ``J d`` (the prediction's Jacobian by finite
differences,
:func:`~blurtrack.detect.gyro.calibsteps.perturbed_models`), ``d`` fitted robustly and
orientation-free (:func:`session_residual`), the calibration
moved by ``d`` and the fit repeated from there (Gauss-Newton: the prediction is nonlinear in
the axes and the bias over a 10-50 ms exposure).

The corrected model predicts the curves the gyro-template pass takes as templates (fewer
rotations and scales to search, and a gate that compares lines with what the dots drew), the
orientation cues and the gyro's check. The endpoints stay the image's: the correction decides
which light is which dot's, and the calibration a lab fits later (``blurtrack calibrate``)
starts again from the streak table and the nominal calibration.

The fit's pieces (:func:`fit_sample`, :func:`fit_system`, :func:`session_residual`,
:func:`session_fit`, and :mod:`~blurtrack.detect.gyro.calibsteps`'s ``corrected_model``) are
the gyro check's too (:mod:`blurtrack.detect.gyro.gyrotrust`), which fits again where the
template pass changed frames.

A correction is kept only where it predicts the voters better than the calibration it starts
from (the median residual falls) and no parameter moved by more than
:data:`MAX_FIT_STEPS` of its finite-difference step (20 % of the
focal length, 100 px, 0.2 rad, 20 ms, 0.2 rad/s, 20 % of a rate): a fit that far from its
start is outside the linearisation it came from, and says that the nominal calibration is
wrong in kind (axes mirrored, another camera's gyro), which ``blurtrack calibrate`` decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.calibsteps import (
    CALIBRATION_STEPS,
    PARAMETERS,
    SCALE_TERMS,
    corrected_model,
    difference,
    largest_step,
    perturbed_models,
)
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import BlurTrackError, ConfigError, CoverageError

#: The scale terms' prior sigma (relative): a MEMS gyro's scale factors and cross-axis
#: sensitivities are within a few per cent of nominal. A shake that turns little about one
#: axis leaves that axis' terms barely observable, trading off against the axes and the focal
#: length; the prior keeps them (and so the fit) near nominal there, where the image's own
#: biases (speckle, lens blur, JPEG) would otherwise run the fit far from its start.
SCALE_PRIOR = 0.02
#: The median length of a 2-D residual whose axes are Gaussian of sigma 1: ``sqrt(2 ln 2)``.
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
#: Fewest session voters per fitted parameter (17 unknowns, 2 equations a streak: three
#: streaks for each unknown, so that no frame's streaks alone can steer the fit).
SESSION_VOTERS_PER_PARAMETER = 3
#: Robust rounds of the session fit and of the frames' similarity fits, dropping residuals
#: over 3x their median (>= 0.5 px).
FIT_ROUNDS = 4
#: Most ``quality_ok`` streaks the session fit is made over (:func:`fit_sample`): each is
#: predicted by the model and the 17 perturbed ones (~235 times the unknowns; a 150-frame
#: dense session has 43 500).
FIT_SAMPLE_VOTERS = 4000
#: Largest fitted calibration error (in steps of :data:`CALIBRATION_STEPS`) that the corrected
#: model applies (the simulator's sessions: within 7). Where the calibration is barely
#: observable (a shake of constant rates: the axes and the bias trade off) the fit runs far
#: along that null space, on the Jacobian's curvature: no calibration to apply; the frames'
#: own similarities test them.
MAX_FIT_STEPS = 20.0
#: Gauss-Newton rounds (each: the Jacobian at the current calibration, a robust fit, a move;
#: :func:`session_fit` over the check's sample,
#: :data:`FIT_SAMPLE_VOTERS` at most). Many voters pay: on
#: ``hard`` seed 2 (8 frames, 933 voters) the corrected model's vectors are 0.57 px from the
#: true ones at the median with all of them, 0.79 px with 400 evenly spaced (a few poorly
#: determined combinations of the axes, readout and bias).
ROUNDS = 2


@dataclass(frozen=True)
class SessionCalibration:
    """The fit's outcome. ``status``: ``fitted`` (``calib`` corrected), ``too_few_voters``,
    ``no_prediction`` (the gyro misses the voters' exposures), ``not_better`` or
    ``implausible`` (``calib`` as given; module text). ``change``: the correction by
    parameter name (:data:`PARAMETERS`, units in the names; zeros where not fitted; the
    refused one where ``implausible``). ``voters``: streaks used; ``residual_before_px`` /
    ``residual_after_px``: their median vector residual against the given and the
    corrected calibration (NaN where not measured)."""

    status: str
    calib: Any
    change: dict[str, float]
    voters: int
    residual_before_px: float
    residual_after_px: float


def session_residual(
    m: np.ndarray,
    p: np.ndarray,
    J: np.ndarray,
    voters: np.ndarray,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(N,)`` ``|m - p - J d|`` (orientation-free: ``m``'s sign nearest ``p + J d``) after the
    calibration error ``d`` fitted robustly over ``voters`` (the first-order change of the
    predicted vectors ``p`` with the calibration: ``J (N, 2, P)``), and ``d``. NaN residuals
    when fewer than :data:`SESSION_VOTERS_PER_PARAMETER` x ``P`` vote.

    ``prior``: ``(centre, sigma)``, ``(P,)`` each: a Gaussian prior on ``d`` (sigma infinite:
    none), weighed against the voters' residual sigma per axis (their median residual of the
    round before over :data:`RAYLEIGH_MEDIAN`; the first round is fitted without it)."""
    n, P = m.shape[0], J.shape[2]
    if int(voters.sum()) < SESSION_VOTERS_PER_PARAMETER * P:
        return np.full(n, np.nan), np.zeros(P)
    q = p.copy()  # the corrected prediction; each measured vector's sign is the nearer to it
    use = voters.copy()
    d = np.zeros(P)
    r = np.hypot(*m.T)
    scale: float | None = None  # the voters' residual scale (px), once there are residuals
    for _ in range(FIT_ROUNDS + 1):
        sign = np.where(np.sum(m * q, axis=1) < 0, -1.0, 1.0)
        y = m * sign[:, None] - p
        A, b = J[use].reshape(-1, P), y[use].reshape(-1)
        if prior is not None and scale is not None:
            centre, sigma = prior
            has = np.isfinite(sigma)
            w = scale / sigma[has]  # rows of the prior: w (d_k - centre_k) = 0
            rows = np.zeros((int(has.sum()), P))
            rows[np.arange(rows.shape[0]), np.flatnonzero(has)] = w
            A, b = np.concatenate([A, rows]), np.concatenate([b, w * centre[has]])
        d = np.linalg.lstsq(A, b, rcond=None)[0]
        q = p + J @ d
        r = np.minimum(np.hypot(*(m - q).T), np.hypot(*(m + q).T))
        med = float(np.median(r[use]))
        # Per axis: the median of a 2-D Gaussian residual's length is sigma sqrt(2 ln 2).
        scale = max(med / RAYLEIGH_MEDIAN, 1e-3)
        cut = max(3.0 * med, 0.5)
        new = voters & (r <= cut)
        if int(new.sum()) < SESSION_VOTERS_PER_PARAMETER * P:
            break
        use = new
    return np.asarray(r), np.asarray(d)


def fit_sample(
    frames: Sequence[FrameStreaks], max_voters: int = FIT_SAMPLE_VOTERS
) -> tuple[list[int], list[np.ndarray]]:
    """The session fit's sample: at most ``max_voters`` ``quality_ok`` streaks spread
    evenly over the session's (in frame order, every ``n``-th), as the positions of the frames
    that hold them and each one's streak indices ``(n_k,)`` (all of them where the session has
    no more). ``max_voters``: at least 1 (default :data:`FIT_SAMPLE_VOTERS`)."""
    if max_voters < 1:
        raise ValueError(f"fit_sample: max_voters must be at least 1, got {max_voters}")
    ok = [
        np.flatnonzero(np.asarray(fs.quality[2], bool))
        if fs.quality is not None
        else np.zeros(0, int)
        for fs in frames
    ]
    total = sum(len(o) for o in ok)
    step = max(1, -(-total // max_voters))  # ceil: at most max_voters
    pos: list[int] = []
    picks: list[np.ndarray] = []
    start = 0  # the session-wide rank of each frame's first voter
    for k, o in enumerate(ok):
        first = (-start) % step  # the first of this frame's voters whose rank is a multiple
        sel = o[first::step]
        start += len(o)
        if len(sel):
            pos.append(k)
            picks.append(sel)
    return pos, picks


def sample_points(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    pos: Sequence[int],
    picks: Sequence[np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sampled streaks (:func:`fit_sample`) as one model call takes them: their time
    midpoints ``(n, 2)`` (px) and their frames' start times and exposures ``(n,)`` (s)."""
    ref = np.concatenate([frames[k].time_mid[s] for k, s in zip(pos, picks, strict=True)])
    sizes = [len(s) for s in picks]
    ft = np.repeat(np.array([timings[k].t_s for k in pos], float), sizes)
    ex = np.repeat(np.array([timings[k].exposure_s for k in pos], float), sizes)
    return ref, ft, ex


def sample_vectors(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    pos: Sequence[int],
    picks: Sequence[np.ndarray],
    points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """``(n, 2)`` predicted start-to-end vectors of the sampled streaks (:func:`fit_sample`),
    one model call; NaN rows for the frames the model does not cover. ``points``: their
    :func:`sample_points`, where already known (a fit predicts the same streaks 38 times)."""
    ref, ft, ex = sample_points(frames, timings, pos, picks) if points is None else points
    try:
        pts = predict_curves(model, ref, ft, ex, 2).pts
        return np.asarray(pts[:, -1] - pts[:, 0])
    except CoverageError:
        pass
    out = []
    for k, s in zip(pos, picks, strict=True):
        try:
            c = predict_curves(
                model, frames[k].time_mid[s], timings[k].t_s, timings[k].exposure_s, 2
            )
            out.append(c.pts[:, -1] - c.pts[:, 0])
        except CoverageError:
            out.append(np.full((len(s), 2), np.nan))
    return np.concatenate(out)


def _scale_prior(
    model: Any, nominal: Any | None, scale_prior: float = SCALE_PRIOR
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`session_residual`'s prior: on the scale terms only, centred where their total
    move from ``nominal``'s (None: none yet) is zero, sigma ``scale_prior`` (relative;
    :data:`SCALE_PRIOR`) in steps."""
    if not scale_prior > 0.0:
        raise ValueError(f"the scale prior's sigma must be positive, got {scale_prior}")
    P = len(PARAMETERS)
    step = CALIBRATION_STEPS["scale"]
    centre, sigma = np.zeros(P), np.full(P, np.inf)
    k = P - len(SCALE_TERMS)
    sigma[k:] = scale_prior / step
    if nominal is not None:
        moved = difference(nominal, model.calib)
        centre[k:] = [-moved[name] / step for name in PARAMETERS[k:]]
    return centre, sigma


def measured_vectors(
    frames: Sequence[FrameStreaks], pos: Sequence[int], picks: Sequence[np.ndarray]
) -> np.ndarray:
    """``(n, 2)`` the measured start-to-end vectors of the sampled streaks
    (:func:`fit_sample`)."""
    return np.concatenate(
        [frames[k].end_b[s] - frames[k].end_a[s] for k, s in zip(pos, picks, strict=True)]
    )


def fit_system(
    frames: Sequence[FrameStreaks], timings: Sequence[FrameTiming], model: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """What :func:`session_residual` fits over the :func:`fit_sample` of the frames'
    ``quality_ok`` streaks: their measured vectors ``m (n, 2)``, ``model``'s predicted ones
    ``p (n, 2)`` and the Jacobian ``J (n, 2, P)`` over :func:`perturbed_models`, of the
    streaks that the model and every perturbed model predict; None where no frame has a
    voter."""
    pos, picks = fit_sample(frames)
    if not pos:
        return None
    m = measured_vectors(frames, pos, picks)
    at = sample_points(frames, timings, pos, picks)
    p = sample_vectors(frames, timings, model, pos, picks, at)
    J = np.stack(
        [sample_vectors(frames, timings, mv, pos, picks, at) - p for mv in perturbed_models(model)],
        axis=2,
    )
    use = np.all(np.isfinite(J), axis=(1, 2)) & np.all(np.isfinite(p), axis=1)
    return m[use], p[use], J[use]


def session_fit(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    max_steps: float | None = MAX_FIT_STEPS,
    nominal: Any | None = None,
    *,
    scale_prior: float = SCALE_PRIOR,
) -> np.ndarray | None:
    """The session's calibration error ``d (17,)`` (:func:`session_residual`, in
    :data:`CALIBRATION_STEPS` units) fitted over the :func:`fit_sample` of the frames'
    ``quality_ok`` streaks (those of the frames that the model and every perturbed model
    predict), or None: too few voters, an error over ``max_steps`` (default
    :data:`MAX_FIT_STEPS`; None: no limit) in a parameter, or one that no calibration holds (a
    gyro scale matrix far from the identity: :class:`~blurtrack.geometry.calibration.Calibration`
    refuses it). The gyro's scale terms have the
    prior ``scale_prior`` (relative sigma, :data:`SCALE_PRIOR`; ``inf``: none) about those of
    ``nominal`` (a calibration; None: the model's own)."""
    system = fit_system(frames, timings, model)
    if system is None:
        return None
    m, p, J = system
    prior = _scale_prior(model, nominal, scale_prior)
    r, d = session_residual(m, p, J, np.ones(len(m), bool), prior)
    if r.size == 0 or np.all(np.isnan(r)):
        return None
    if max_steps is not None and float(np.max(np.abs(d))) > max_steps:
        return None
    try:  # a correction no calibration can hold (a gyro scale matrix far from the identity)
        corrected_model(model, d)
    except ConfigError:
        return None
    return d


def _median_residual(m: np.ndarray, p: np.ndarray) -> float:
    """Median orientation-free ``|m - p|`` (px) over the rows the model predicts."""
    r = np.minimum(np.hypot(*(m - p).T), np.hypot(*(m + p).T))
    r = r[np.isfinite(r)]
    return float(np.median(r)) if r.size else float("nan")


def fit_session_calibration(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
    *,
    scale_prior: float = SCALE_PRIOR,
) -> SessionCalibration:
    """The session's calibration error from the ``covered`` frames' ``quality_ok`` streaks
    (see the module text); ``model``: the blur model of the calibration to correct (its
    ``calib``; the corrected one is returned, not a model). ``scale_prior``: the prior on the
    gyro's scale terms (:func:`session_fit`)."""
    zero = dict.fromkeys(PARAMETERS, 0.0)
    sub = [frames[k] for k in covered]
    tim = [timings[k] for k in covered]
    pos, picks = fit_sample(sub)
    n = sum(len(s) for s in picks)
    if n < SESSION_VOTERS_PER_PARAMETER * len(PARAMETERS):
        return SessionCalibration("too_few_voters", model.calib, zero, n, np.nan, np.nan)
    m = measured_vectors(sub, pos, picks)
    current = model
    try:
        at = sample_points(sub, tim, pos, picks)
        before = _median_residual(m, sample_vectors(sub, tim, model, pos, picks, at))
        for _ in range(ROUNDS):
            # No limit per round: the rounds may go far; the whole move is judged below.
            d = session_fit(
                sub, tim, current, max_steps=None, nominal=model.calib, scale_prior=scale_prior
            )
            if d is None:
                break
            current = corrected_model(current, d)
        after = _median_residual(m, sample_vectors(sub, tim, current, pos, picks, at))
    except BlurTrackError:
        return SessionCalibration("no_prediction", model.calib, zero, n, np.nan, np.nan)
    if not np.isfinite(before):
        return SessionCalibration("no_prediction", model.calib, zero, n, before, after)
    change = difference(model.calib, current.calib)
    if not after < before:
        return SessionCalibration("not_better", model.calib, zero, n, before, after)
    if largest_step(change) > MAX_FIT_STEPS:
        return SessionCalibration("implausible", model.calib, change, n, before, after)
    return SessionCalibration("fitted", current.calib, change, n, before, after)
