"""The gyro's check of ``quality_ok`` ends: a per-frame test that no single-streak image measure
can make (issue 45).

Every streak of a frame is the same camera motion seen from a different pixel, so the gyro
predicts each one's start-to-end vector and the curve between
(:func:`blurtrack.detect.gyro.gyrocurve.predict_curves`, at the streak's measured time
midpoint). Two things follow, checked on the streaks the image found ``quality_ok``:

- ``gyro_mismatch``: the measured start-to-end vector against the predicted one, after the
  session's calibration error fitted to first order: the initial calibration's focal length,
  principal point, ``R_cam_imu`` (three angles), time offset, readout and gyro bias (three
  rates) are the session's, the same for every frame, so the predicted vectors ``p`` of all
  the checked frames change with them by ``J d`` (``J``: the prediction's Jacobian, by finite
  differences over models perturbed by :data:`CALIBRATION_STEPS`; ``d``: the error). ``d`` is
  fitted robustly, orientation-free, over a sample of the ``quality_ok`` streaks spread over
  every checked frame (:func:`session_fit`, :func:`fit_sample`: at most
  :data:`FIT_SAMPLE_VOTERS`, so that the perturbed models predict those alone;
  :func:`session_residual`, at least :data:`SESSION_VOTERS_PER_PARAMETER` per unknown) and
  the residual ``|m - q|`` tested, ``q`` the vector that the calibration corrected by ``d``
  predicts (:func:`corrected_model`; ``p + J d`` but for the curvature of a few steps). The
  vector is the difference of the two ends, so an
  end ``e`` px off moves it by ``e``: a residual above ``source.gyro_vector_tol_px`` means an
  end is off by about that much. Eleven unknowns for the whole session cannot absorb a bias
  that one frame's streaks share (saturated ends 2-3 px long in one frame), which a fit per
  frame does. Where the corrected model does not cover a frame, or the session has too few
  voters (or a fit far off, :data:`MAX_FIT_STEPS`), the frame's own similarity ``m = z p``
  (:func:`vector_residual`, :data:`MIN_VOTERS` at least, else not checked) is the fallback.
- ``hairpin``: where the shake turns within the exposure, the dot's path doubles back, and the
  streak's visible extremities are its turning points, not its start and end: the depth of the
  predicted start and end inside the predicted path's extremities along the chord
  (:func:`hairpin_depth`) is how far the measured ends are off. Above
  ``source.hairpin_depth_px`` the ends are not trusted, unless the gyro-template pass measured
  that streak along its predicted curve (:attr:`~blurtrack.detect.frame.FrameStreaks.along_curve`:
  a hairpin as its two arms).

The two tolerances share the 2 px end gate of the contract (``quality_ok`` ends within 2 px):
three quarters to the measured vector, one quarter to the unseen depth
(:class:`blurtrack.detect.params.SourceParams`). Without a gyro nothing here runs: a hairpin is
then seen by the image only where it is wide enough to fold the streak (``looped``, shape).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from blurtrack.detect.forkmap import batch_positions, fork_map
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.orientation import FrameTiming
from blurtrack.detect.params import SourceParams
from blurtrack.errors import CoverageError

#: Samples per predicted curve (uniform in time): at a turn the dot is slow, so its depth is
#: sampled to a small fraction of a pixel (the rest of the curve is only needed at its ends):
#: a turn of rate ``w`` px/s^2 by at most ``w (T / 32)^2 / 2`` (T the exposure), ~0.05 px on
#: a 24 px excursion turning at 3/4 of the exposure, a tenth of ``source.hairpin_depth_px``
#: (33 samples: a quarter of that, 2 of 44 726 streaks of a 150-frame dense session otherwise,
#: both right; at 1.5x the predictions' time).
PATH_SAMPLES = 17
#: Fewest ``quality_ok`` streaks in a frame for its similarity fit (as the shape consensus).
MIN_VOTERS = 5
#: The calibration parameters of the session's fit and the step of each finite difference:
#: focal length (relative), principal point (px), ``R_cam_imu`` (rad about each axis), time
#: offset and readout (s), gyro bias (rad/s about each axis). Each step moves a dot ~1-10 px
#: over an exposure (f ~1000 px, rates ~1 rad/s, 10-50 ms): far above the predictions'
#: rounding, and where the prediction is still linear (its curvature costs ~step^2).
CALIBRATION_STEPS = {"focal": 0.01, "pp": 5.0, "axes": 0.01, "time": 1e-3, "bias": 0.01}
#: Fewest session voters per fitted parameter (11 unknowns, 2 equations a streak: three
#: streaks for each unknown, so that no frame's streaks alone can steer the fit).
SESSION_VOTERS_PER_PARAMETER = 3
#: Robust rounds of the similarity fit, dropping residuals over 3x their median (>= 0.5 px).
FIT_ROUNDS = 4
#: Streaks per batched model call (bounds the temporaries: samples x streaks points).
BATCH_STREAKS = 4000
#: Most ``quality_ok`` streaks the session fit is made over (:func:`fit_sample`): each is
#: predicted by the model and the 11 perturbed ones (~360 times the unknowns; a 150-frame
#: dense session has 43 500).
FIT_SAMPLE_VOTERS = 4000
#: Largest fitted calibration error (in steps of :data:`CALIBRATION_STEPS`) that the corrected
#: model applies (the simulator's sessions: within 7). Where the calibration is barely
#: observable (a shake of constant rates: the axes and the bias trade off) the fit runs far
#: along that null space, on the Jacobian's curvature: no calibration to apply; the frames'
#: own similarities test them.
MAX_FIT_STEPS = 20.0


@dataclass(frozen=True)
class GyroCheck:
    """Per streak of a frame: ``residual`` (px, NaN: not checked), ``depth`` (px)."""

    residual: np.ndarray
    depth: np.ndarray


def _batches(frames: Sequence[FrameStreaks]) -> list[list[int]]:
    """The positions of the frames with streaks, in order, in batches of at most
    :data:`BATCH_STREAKS` streaks (a larger frame alone)."""
    return batch_positions(((k, len(fs)) for k, fs in enumerate(frames) if len(fs)), BATCH_STREAKS)


def _predicted_batch(
    frames: Sequence[FrameStreaks] | Sequence[_Pending],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    samples: int,
) -> list[np.ndarray | None]:
    """:func:`predicted_curves` of the frames ``group`` (one batch of :func:`_batches`): one
    model call, frame by frame where it fails (only those the gyro misses are lost)."""
    ref = np.concatenate([frames[k].time_mid for k in group])
    ft = np.concatenate([np.full(len(frames[k]), timings[k].t_s) for k in group])
    ex = np.concatenate([np.full(len(frames[k]), timings[k].exposure_s) for k in group])
    try:
        pts = predict_curves(model, ref, ft, ex, samples).pts
    except CoverageError:
        out: list[np.ndarray | None] = [None] * len(group)
        if len(group) == 1:
            return out
        for j, k in enumerate(group):
            with contextlib.suppress(CoverageError):
                out[j] = predict_curves(
                    model, frames[k].time_mid, timings[k].t_s, timings[k].exposure_s, samples
                ).pts
        return out
    bounds = np.cumsum([len(frames[k]) for k in group])[:-1]
    return list(np.split(pts, bounds))


def predicted_curves(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    samples: int = PATH_SAMPLES,
) -> list[np.ndarray | None]:
    """``(N, samples, 2)`` predicted curves of each frame's streaks at their time midpoints
    (None where the gyro falls short), batched over frames (:func:`_batches`). Every sample
    is predicted on its own, so ``samples=2`` gives the same two ends as the whole path at a
    fraction of the cost."""
    out: list[np.ndarray | None] = [None] * len(frames)
    for group in _batches(frames):
        for k, c in zip(
            group, _predicted_batch(frames, timings, model, group, samples), strict=True
        ):
            out[k] = c
    return out


def hairpin_depth(pts: np.ndarray) -> np.ndarray:
    """``(N,)`` how far the start and end of curves ``pts (N, S, 2)`` lie inside the curve's
    extremities along its chord (the larger of the two; 0 for a path that never doubles back).
    A curve that returns to its start (no chord) is measured along its principal axis."""
    if pts.shape[0] == 0:
        return np.zeros(0)
    chord = pts[:, -1] - pts[:, 0]
    c = pts - pts.mean(axis=1, keepdims=True)
    cov = np.einsum("nsi,nsj->nij", c, c)
    _, vecs = np.linalg.eigh(cov)
    axis = vecs[:, :, -1]
    L = np.hypot(*chord.T)
    small = L < 1e-6
    u = np.where(small[:, None], axis, chord / np.where(small, 1.0, L)[:, None])
    proj = np.einsum("nsk,nk->ns", pts, u)
    d0 = proj[:, 0] - proj.min(axis=1)
    d1 = proj.max(axis=1) - proj[:, -1]
    if small.any():  # no direction from start to end: either end may be the inner one
        lo, hi = proj.min(axis=1), proj.max(axis=1)
        d0 = np.where(small, np.minimum(proj[:, 0] - lo, hi - proj[:, 0]), d0)
        d1 = np.where(small, np.minimum(proj[:, -1] - lo, hi - proj[:, -1]), d1)
    return np.asarray(np.maximum(d0, d1))


def vector_residual(m: np.ndarray, p: np.ndarray, voters: np.ndarray) -> np.ndarray:
    """``(N,)`` ``|m - z p|`` (orientation-free: ``p``'s sign nearest ``m``) after the robust
    similarity ``z`` fitted over ``voters``; NaN when fewer than :data:`MIN_VOTERS` vote."""
    n = m.shape[0]
    if int(voters.sum()) < MIN_VOTERS:
        return np.full(n, np.nan)
    sign = np.where(np.sum(m * p, axis=1) < 0, -1.0, 1.0)
    zm = m[:, 0] + 1j * m[:, 1]
    zp = (p[:, 0] + 1j * p[:, 1]) * sign
    use = voters.copy()
    r = np.zeros(n)
    for _ in range(FIT_ROUNDS):
        den = float(np.sum(np.abs(zp[use]) ** 2))
        z = complex(np.sum(np.conj(zp[use]) * zm[use])) / den if den > 0 else 1.0
        r = np.abs(zm - z * zp)
        cut = max(3.0 * float(np.median(r[use])), 0.5)
        new = voters & (r <= cut)
        if int(new.sum()) < MIN_VOTERS:
            break
        use = new
    return np.asarray(r)


def _rotation(v: np.ndarray) -> np.ndarray:
    """The rotation matrix of rotation vector ``v`` (rad)."""
    th = float(np.linalg.norm(v))
    if th == 0.0:
        return np.eye(3)
    a = v / th
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.asarray(np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K)


def perturbed_models(model: Any) -> list[Any]:
    """``model`` with each calibration parameter of :data:`CALIBRATION_STEPS` moved by its
    step, in that order (the columns of the prediction's Jacobian)."""
    c = model.calib
    fx, fy, cx, cy = c.camera.intrinsics
    bias = np.asarray(c.gyro_bias_radps, float)
    fs, pp, ang, dt, rate = (CALIBRATION_STEPS[k] for k in ("focal", "pp", "axes", "time", "bias"))
    calibs = [
        c.with_(intrinsics=(fx * (1.0 + fs), fy * (1.0 + fs), cx, cy)),
        c.with_(intrinsics=(fx, fy, cx + pp, cy)),
        c.with_(intrinsics=(fx, fy, cx, cy + pp)),
        *(c.with_(R_cam_imu=_rotation(ang * ax) @ c.R_cam_imu) for ax in np.eye(3)),
        c.with_(timeshift_cam_imu_s=c.timeshift_cam_imu_s + dt),
        c.with_(readout_s=c.camera.readout_s + dt),
        *(c.with_(gyro_bias_radps=bias + rate * ax) for ax in np.eye(3)),
    ]
    # The model's gyro is already resampled: no second resampling.
    return [replace(model, calib=k, gyro_upsample=1) for k in calibs]


def session_residual(
    m: np.ndarray, p: np.ndarray, J: np.ndarray, voters: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(N,)`` ``|m - p - J d|`` (orientation-free: ``m``'s sign nearest ``p + J d``) after the
    calibration error ``d`` fitted robustly over ``voters`` (the first-order change of the
    predicted vectors ``p`` with the calibration: ``J (N, 2, P)``), and ``d``. NaN residuals
    when fewer than :data:`SESSION_VOTERS_PER_PARAMETER` x ``P`` vote."""
    n, P = m.shape[0], J.shape[2]
    if int(voters.sum()) < SESSION_VOTERS_PER_PARAMETER * P:
        return np.full(n, np.nan), np.zeros(P)
    q = p.copy()  # the corrected prediction; each measured vector's sign is the nearer to it
    use = voters.copy()
    d = np.zeros(P)
    r = np.hypot(*m.T)
    for _ in range(FIT_ROUNDS + 1):
        sign = np.where(np.sum(m * q, axis=1) < 0, -1.0, 1.0)
        y = m * sign[:, None] - p
        d = np.linalg.lstsq(J[use].reshape(-1, P), y[use].reshape(-1), rcond=None)[0]
        q = p + J @ d
        r = np.minimum(np.hypot(*(m - q).T), np.hypot(*(m + q).T))
        cut = max(3.0 * float(np.median(r[use])), 0.5)
        new = voters & (r <= cut)
        if int(new.sum()) < SESSION_VOTERS_PER_PARAMETER * P:
            break
        use = new
    return np.asarray(r), np.asarray(d)


def check_frame(fs: FrameStreaks, curves: np.ndarray, ok: np.ndarray) -> GyroCheck:
    """The :class:`GyroCheck` of one frame's streaks against their predicted ``curves``, the
    frame's similarity fitted over the streaks ``ok`` (the fallback of :func:`check_frames`
    where the session's fit does not apply)."""
    m = fs.end_b - fs.end_a
    p = curves[:, -1] - curves[:, 0]
    return GyroCheck(vector_residual(m, p, ok), hairpin_depth(curves))


def apply_check(
    fs: FrameStreaks, check: GyroCheck, p: SourceParams
) -> tuple[np.ndarray, np.ndarray]:
    """``fs.quality``'s ``quality_ok`` and ``reason`` after the check: the ``quality_ok``
    streaks that fail it demoted (``hairpin`` first, then ``gyro_mismatch``), the streaks
    with exactly one image doubt (:attr:`~blurtrack.detect.frame.FrameStreaks.one_doubt`: a
    crossing, one lit end, a blown-out core or a shape off the consensus) that pass it
    confirmed (``ok``: the gyro measured the start-to-end vector the image doubted); other
    streaks keep their image reason."""
    assert fs.quality is not None
    ok = np.asarray(fs.quality[2], bool).copy()
    reason = np.asarray(fs.quality[4], object).copy()
    along = fs.along_curve if len(fs.along_curve) == len(fs) else np.zeros(len(fs), bool)
    single = fs.one_doubt if len(fs.one_doubt) == len(fs) else np.zeros(len(fs), bool)
    with np.errstate(invalid="ignore"):  # NaN: not checked (neither off nor confirmed)
        fits = check.residual <= p.gyro_vector_tol_px
        off = ok & (check.residual > p.gyro_vector_tol_px)
        turns = (check.depth > p.hairpin_depth_px) & ~along
    deep = ok & turns
    confirmed = single & ~ok & fits & ~turns
    reason[off] = "gyro_mismatch"
    reason[deep] = "hairpin"
    reason[confirmed] = "ok"
    ok = (ok & ~(off | deep)) | confirmed
    return ok, reason


def _vectors_of_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    depth: bool,
) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
    """Per frame of ``group``: the predicted start-to-end vectors ``(N, 2)`` and, with
    ``depth``, the :func:`hairpin_depth` of the whole predicted paths (:data:`PATH_SAMPLES`;
    without, only the two ends are predicted); None where the gyro falls short. All that
    :func:`check_frames` needs of a model's curves, so that little comes back from a worker."""
    curves = _predicted_batch(frames, timings, model, group, PATH_SAMPLES if depth else 2)
    return [
        None if c is None else (c[:, -1] - c[:, 0], hairpin_depth(c) if depth else None)
        for c in curves
    ]


def fit_sample(frames: Sequence[FrameStreaks]) -> tuple[list[int], list[np.ndarray]]:
    """The session fit's sample: at most :data:`FIT_SAMPLE_VOTERS` ``quality_ok`` streaks spread
    evenly over the session's (in frame order, every ``n``-th), as the positions of the frames
    that hold them and each one's streak indices ``(n_k,)`` (all of them where the session has
    no more)."""
    ok = [
        np.flatnonzero(np.asarray(fs.quality[2], bool))
        if fs.quality is not None
        else np.zeros(0, int)
        for fs in frames
    ]
    total = sum(len(o) for o in ok)
    step = max(1, -(-total // FIT_SAMPLE_VOTERS))  # ceil: at most FIT_SAMPLE_VOTERS
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


def corrected_model(model: Any, d: np.ndarray) -> Any:
    """``model`` with the calibration error ``d (11,)`` of :func:`session_residual` applied (in
    :data:`CALIBRATION_STEPS` units, the order of :func:`perturbed_models`: ``d = e_i`` is the
    ``i``-th perturbed model; the readout no less than 0)."""
    c = model.calib
    fx, fy, cx, cy = c.camera.intrinsics
    bias = np.asarray(c.gyro_bias_radps, float)
    fs, pp, ang, dt, rate = (CALIBRATION_STEPS[k] for k in ("focal", "pp", "axes", "time", "bias"))
    e = [float(v) for v in d]  # python floats, as the perturbed models' parameters
    turn = ang * np.asarray(e[3:6])
    calib = c.with_(
        intrinsics=(fx * (1.0 + fs * e[0]), fy * (1.0 + fs * e[0]), cx + pp * e[1], cy + pp * e[2]),
        R_cam_imu=_rotation(turn) @ c.R_cam_imu if np.any(turn) else c.R_cam_imu,
        timeshift_cam_imu_s=c.timeshift_cam_imu_s + dt * e[6],
        readout_s=max(c.camera.readout_s + dt * e[7], 0.0),
        gyro_bias_radps=bias + rate * np.asarray(e[8:11]) if any(e[8:11]) else c.gyro_bias_radps,
    )
    return replace(model, calib=calib, gyro_upsample=1)


def sample_vectors(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    pos: Sequence[int],
    picks: Sequence[np.ndarray],
) -> np.ndarray:
    """``(n, 2)`` predicted start-to-end vectors of the sampled streaks (:func:`fit_sample`),
    one model call; NaN rows for the frames the model does not cover."""
    ref = np.concatenate([frames[k].time_mid[s] for k, s in zip(pos, picks, strict=True)])
    ft = np.concatenate([np.full(len(s), timings[k].t_s) for k, s in zip(pos, picks, strict=True)])
    ex = np.concatenate(
        [np.full(len(s), timings[k].exposure_s) for k, s in zip(pos, picks, strict=True)]
    )
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


def session_fit(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    max_steps: float | None = MAX_FIT_STEPS,
) -> np.ndarray | None:
    """The session's calibration error ``d (11,)`` (:func:`session_residual`, in
    :data:`CALIBRATION_STEPS` units) fitted over the :func:`fit_sample` of the frames'
    ``quality_ok`` streaks (those of the frames that the model and every perturbed model
    predict), or None: too few voters, or an error over ``max_steps`` (default
    :data:`MAX_FIT_STEPS`; None: no limit) in a parameter."""
    pos, picks = fit_sample(frames)
    if not pos:
        return None
    m = np.concatenate(
        [frames[k].end_b[s] - frames[k].end_a[s] for k, s in zip(pos, picks, strict=True)]
    )
    p = sample_vectors(frames, timings, model, pos, picks)
    J = np.stack(
        [sample_vectors(frames, timings, mv, pos, picks) - p for mv in perturbed_models(model)],
        axis=2,
    )
    use = np.all(np.isfinite(J), axis=(1, 2)) & np.all(np.isfinite(p), axis=1)
    r, d = session_residual(m[use], p[use], J[use], np.ones(int(use.sum()), bool))
    if r.size == 0 or np.all(np.isnan(r)):
        return None
    if max_steps is not None and float(np.max(np.abs(d))) > max_steps:
        return None
    return d


@dataclass(frozen=True)
class _Pending:
    """A frame's streaks still to predict: their time midpoints ``(n, 2)`` (px)."""

    time_mid: np.ndarray

    def __len__(self) -> int:
        return len(self.time_mid)


def _known_paths(
    frames: Sequence[FrameStreaks], pos: Sequence[int], known: Mapping[int, np.ndarray]
) -> tuple[dict[int, np.ndarray], list[_Pending]]:
    """Of ``frames`` (``pos``: their positions in ``known``'s keys), the known curves of the
    streaks inside the image, by frame (only those of :data:`PATH_SAMPLES`, one per inside
    streak), and per frame the streaks still to predict (all, or the clipped ones)."""
    have: dict[int, np.ndarray] = {}
    pending: list[_Pending] = []
    for j, (fs, k) in enumerate(zip(frames, pos, strict=True)):
        c = known.get(k)
        inside = ~fs.flags["clipped"] if len(fs) else np.zeros(0, bool)
        if c is not None and c.shape == (int(inside.sum()), PATH_SAMPLES, 2):
            have[j] = c
            pending.append(_Pending(fs.time_mid[~inside]))
        else:
            pending.append(_Pending(fs.time_mid))
    return have, pending


def _path_batches(frames: Sequence[FrameStreaks], pending: Sequence[_Pending]) -> list[list[int]]:
    """The positions of the frames with streaks, in order, in batches of at most
    :data:`BATCH_STREAKS` streaks to predict, or a frame's depth to measure (an eighth of
    a predicted streak's cost); exactly :func:`_batches` where every streak is pending."""
    weighted = (
        (k, len(todo) if len(todo) == len(fs) else len(todo) + len(fs) // 8)
        for k, (fs, todo) in enumerate(zip(frames, pending, strict=True))
        if len(fs)
    )
    return batch_positions(weighted, BATCH_STREAKS)


def _paths_of_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    have: Mapping[int, np.ndarray],
    pending: Sequence[_Pending],
) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
    """:func:`_vectors_of_batch` (with the depth) of the frames ``group``, their ``pending``
    streaks predicted in one model call, the rest taken from ``have``."""
    todo = [k for k in group if len(pending[k])]
    pred = dict(
        zip(todo, _predicted_batch(pending, timings, model, todo, PATH_SAMPLES), strict=True)
        if todo
        else ()
    )
    out: list[tuple[np.ndarray, np.ndarray | None] | None] = []
    for k in group:
        c = pred.get(k) if len(pending[k]) else np.zeros((0, PATH_SAMPLES, 2))
        if c is not None and k in have:
            inside = ~frames[k].flags["clipped"]
            whole = np.empty((len(frames[k]), PATH_SAMPLES, 2))
            whole[inside] = have[k]
            whole[~inside] = c
            c = whole
        out.append(None if c is None else (c[:, -1] - c[:, 0], hairpin_depth(c)))
    return out


def check_frames(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
    p: SourceParams,
    workers: int = 1,
    meanwhile: Callable[[], None] | None = None,
    known: Mapping[int, np.ndarray] | None = None,
    fitted: bool = False,
) -> int:
    """Apply the check to the ``covered`` frames' ``quality`` in place; returns how many
    frames were checked (those with a prediction and enough ``quality_ok`` streaks). The
    vectors are tested against the session's fit where the corrected model predicts the frame
    (the calibration error :func:`session_fit` fits over a sample of the voters, applied by
    :func:`corrected_model`; the residual ``|m - q|``, orientation-free, ``q`` that model's
    predicted vector), else against the frame's similarity.

    The model's whole paths (batch by batch: each batch the very model call of one process)
    are predicted in ``workers`` forked processes (:func:`blurtrack.detect.forkmap.fork_map`),
    the same numbers as in one; meanwhile this process runs ``meanwhile`` (first, without
    workers), the fit and the corrected model's predictions. ``known``: by position in
    ``frames``, the curves ``(n_inside, PATH_SAMPLES, 2)`` this very model predicted for a
    frame's streaks inside the image (the template pass's gate,
    :attr:`blurtrack.detect.gyro.refinepass.TemplatePass.curves`): only its other streaks
    are predicted here. ``fitted``: ``model`` is already corrected by the session's error
    fitted over these very streaks (:mod:`blurtrack.detect.gyro.sessioncalib`, no frame
    changed since): the vectors are tested against its own predictions, with no fit again."""
    keep = [k for k in covered if frames[k].quality is not None]
    sub = [frames[k] for k in keep]
    tim = [timings[k] for k in keep]
    batches = _batches(sub)
    have, pending = _known_paths(sub, keep, known or {})
    groups = _path_batches(sub, pending)
    fixed: list[list[tuple[np.ndarray, np.ndarray | None] | None]] = []

    def fit_meanwhile() -> None:
        if meanwhile is not None:
            meanwhile()
        if fitted:
            return
        d = session_fit(sub, tim, model)
        if d is None:
            return
        fix = corrected_model(model, d)
        out: list[tuple[np.ndarray, np.ndarray | None] | None] = [None] * len(sub)
        for group in batches:
            for k, v in zip(
                group, _vectors_of_batch(sub, tim, fix, group, depth=False), strict=True
            ):
                out[k] = v
        fixed.append(out)

    def one(b: int) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
        if not have:  # nothing known: the very batches and model calls of _vectors_of_batch
            return _vectors_of_batch(sub, tim, model, groups[b], depth=True)
        return _paths_of_batch(sub, tim, model, groups[b], have, pending)

    main: list[tuple[np.ndarray, np.ndarray | None] | None] = [None] * len(sub)
    for b, got in zip(
        range(len(groups)),
        fork_map(one, range(len(groups)), workers, 1, fit_meanwhile),
        strict=True,
    ):
        for k, v in zip(groups[b], got, strict=True):
            main[k] = v
    checked = 0
    for j, (fs, c) in enumerate(zip(sub, main, strict=True)):
        if c is None or fs.quality is None:
            continue
        ok0 = np.asarray(fs.quality[2], bool)
        m = fs.end_b - fs.end_a
        pv, depth = c
        assert depth is not None  # the model's own paths: whole
        v = fixed[0][j] if fixed else (c if fitted else None)
        if v is not None:
            res = np.minimum(np.hypot(*(m - v[0]).T), np.hypot(*(m + v[0]).T))
        else:
            res = vector_residual(m, pv, ok0)
        chk = GyroCheck(np.asarray(res), depth)
        if np.all(np.isnan(chk.residual)) and not np.any(ok0):
            continue
        ok, reason = apply_check(fs, chk, p)
        qual = list(fs.quality)
        qual[2], qual[4] = ok, reason
        fs.quality = tuple(qual)
        checked += 1
    return checked
