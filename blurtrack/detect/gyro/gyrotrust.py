"""The gyro's check of ``quality_ok`` ends: a per-frame test that no single-streak image measure
can make (issue 45).

Every streak of a frame is the same camera motion seen from a different pixel, so the gyro
predicts each one's start-to-end vector and the curve between
(:func:`blurtrack.detect.gyro.gyrocurve.predict_curves`, at the streak's measured time
midpoint). Two things follow, checked on the streaks the image found ``quality_ok``:

- ``gyro_mismatch``: the measured start-to-end vector against the predicted one, after the
  frame's correction of the session's initial calibration, derived to first order in its
  errors: the focal length and a roll of ``R_cam_imu`` scale and turn the predicted vector
  (``z p``, ``z`` complex); a tilt of ``R_cam_imu`` (the rotation differs by ``d x omega``),
  a principal point off (about the optical axis: a shift common to the frame) and the gyro's
  time offset (the exposure's rotation differs by the rate change over it times the offset)
  add a small rotation ``w0`` seen through the camera's motion field ``B(x)`` (the image
  motion of a unit rotation about each camera axis at the time midpoint ``x``); the readout
  error moves each row's window by an offset proportional to the row, so ``w1 row``. So
  ``m = z p + B(x) (w0 + w1 row)``, 8 unknowns, fitted robustly per frame (orientation-free,
  over the frame's ``quality_ok`` streaks; the similarity alone where fewer than
  :data:`FIELD_VOTERS` vote, none below :data:`MIN_VOTERS`), and the residual tested. The
  vector is the difference of the two ends, so an end ``e`` px off moves it by ``e``: a
  residual above ``source.gyro_vector_tol_px`` means an end is off by about that much. A frame
  whose streaks are all off alike (a blur every streak shares) is absorbed by the fit: that is
  left to the image measures.
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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.orientation import FrameTiming
from blurtrack.detect.params import SourceParams
from blurtrack.errors import CoverageError

#: Samples per predicted curve (uniform in time): at a turn the dot is slow, so its depth is
#: sampled to a small fraction of a pixel (the rest of the curve is only needed at its ends).
PATH_SAMPLES = 33
#: Fewest ``quality_ok`` streaks in a frame for its similarity fit (as the shape consensus).
MIN_VOTERS = 5
#: Fewest voters for the frame's full correction (8 unknowns, 2 equations a streak: 4 streaks
#: determine it; three times that, so that one bad end cannot steer it), else the similarity.
FIELD_VOTERS = 12
#: Robust rounds of the similarity fit, dropping residuals over 3x their median (>= 0.5 px).
FIT_ROUNDS = 4
#: Streaks per batched model call (bounds the temporaries: samples x streaks points).
BATCH_STREAKS = 4000


@dataclass(frozen=True)
class GyroCheck:
    """Per streak of a frame: ``residual`` (px, NaN: not checked), ``depth`` (px)."""

    residual: np.ndarray
    depth: np.ndarray


def predicted_curves(
    frames: Sequence[FrameStreaks], timings: Sequence[FrameTiming], model: Any
) -> list[np.ndarray | None]:
    """``(N, PATH_SAMPLES, 2)`` predicted curves of each frame's streaks at their time
    midpoints (None where the gyro falls short), batched over frames."""
    out: list[np.ndarray | None] = [None] * len(frames)
    todo = [k for k, fs in enumerate(frames) if len(fs)]
    start = 0
    while start < len(todo):
        group: list[int] = []
        count = 0
        while start < len(todo) and (
            not group or count + len(frames[todo[start]]) <= BATCH_STREAKS
        ):
            group.append(todo[start])
            count += len(frames[todo[start]])
            start += 1
        ref = np.concatenate([frames[k].time_mid for k in group])
        ft = np.concatenate([np.full(len(frames[k]), timings[k].t_s) for k in group])
        ex = np.concatenate([np.full(len(frames[k]), timings[k].exposure_s) for k in group])
        try:
            pts = predict_curves(model, ref, ft, ex, PATH_SAMPLES).pts
        except CoverageError:
            if len(group) == 1:
                continue
            for k in group:  # frame by frame: only those the gyro misses are lost
                with contextlib.suppress(CoverageError):
                    out[k] = predict_curves(
                        model,
                        frames[k].time_mid,
                        timings[k].t_s,
                        timings[k].exposure_s,
                        PATH_SAMPLES,
                    ).pts
            continue
        bounds = np.cumsum([len(frames[k]) for k in group])[:-1]
        for k, part in zip(group, np.split(pts, bounds), strict=True):
            out[k] = part
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


def _correction_basis(ps: np.ndarray, mid: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``(N, 2, 8)``: the x and y rows of the frame's correction of the predicted vectors
    ``ps`` at time midpoints ``mid`` (camera matrix ``K``), see :func:`vector_residual`."""
    f = float(K[0, 0])
    x = mid[:, 0] - float(K[0, 2])
    y = mid[:, 1] - float(K[1, 2])
    # The image motion of a small rotation about the camera's x, y, z axes (per radian).
    bx = np.stack([x * y / f, -(f + x * x / f), y], axis=1)
    by = np.stack([f + y * y / f, -x * y / f, -x], axis=1)
    row = (y / max(2.0 * float(K[1, 2]), 1.0))[:, None]  # the row, -1/2..1/2 of the frame
    ex = np.column_stack([ps[:, 0], -ps[:, 1], bx, bx * row])
    ey = np.column_stack([ps[:, 1], ps[:, 0], by, by * row])
    return np.stack([ex, ey], axis=1)


def vector_residual(
    m: np.ndarray,
    p: np.ndarray,
    voters: np.ndarray,
    mid: np.ndarray | None = None,
    K: np.ndarray | None = None,
) -> np.ndarray:
    """``(N,)`` residual of the measured vectors ``m`` (orientation-free: ``p``'s sign nearest
    ``m``) after the frame's correction of the predicted ``p``, fitted robustly over
    ``voters``: with the time midpoints ``mid`` and camera matrix ``K`` and at least
    :data:`FIELD_VOTERS` voters ``m = z p + B(x) (w0 + w1 row)`` (module docstring), else the
    similarity ``m = z p``; NaN when fewer than :data:`MIN_VOTERS` vote."""
    n = m.shape[0]
    if int(voters.sum()) < MIN_VOTERS:
        return np.full(n, np.nan)
    sign = np.where(np.sum(m * p, axis=1) < 0, -1.0, 1.0)
    ps = p * sign[:, None]
    if mid is not None and K is not None and int(voters.sum()) >= FIELD_VOTERS:
        E = _correction_basis(ps, mid, K)
    else:  # the similarity m = z p alone
        E = np.stack(
            [np.column_stack([ps[:, 0], -ps[:, 1]]), np.column_stack([ps[:, 1], ps[:, 0]])],
            axis=1,
        )
    use = voters.copy()
    r = np.zeros(n)
    for _ in range(FIT_ROUNDS):
        A = E[use].reshape(-1, E.shape[2])
        coef = np.linalg.lstsq(A, m[use].reshape(-1), rcond=None)[0]
        r = np.hypot(*(m - E @ coef).T)
        cut = max(3.0 * float(np.median(r[use])), 0.5)
        new = voters & (r <= cut)
        if int(new.sum()) < MIN_VOTERS:
            break
        use = new
    return np.asarray(r)


def check_frame(
    fs: FrameStreaks, curves: np.ndarray, ok: np.ndarray, K: np.ndarray | None = None
) -> GyroCheck:
    """The :class:`GyroCheck` of one frame's streaks against their predicted ``curves``, the
    frame's correction fitted over the streaks ``ok`` (``K``: the camera matrix of the
    prediction; None: a similarity only)."""
    m = fs.end_b - fs.end_a
    p = curves[:, -1] - curves[:, 0]
    return GyroCheck(vector_residual(m, p, ok, fs.time_mid, K), hairpin_depth(curves))


def apply_check(
    fs: FrameStreaks, check: GyroCheck, p: SourceParams
) -> tuple[np.ndarray, np.ndarray]:
    """``fs.quality``'s ``quality_ok`` and ``reason`` with the ``quality_ok`` streaks that fail
    the check demoted (``hairpin`` first, then ``gyro_mismatch``); other streaks keep their
    image reason."""
    assert fs.quality is not None
    ok = np.asarray(fs.quality[2], bool).copy()
    reason = np.asarray(fs.quality[4], object).copy()
    along = fs.along_curve if len(fs.along_curve) == len(fs) else np.zeros(len(fs), bool)
    with np.errstate(invalid="ignore"):
        off = ok & (check.residual > p.gyro_vector_tol_px)
        deep = ok & (check.depth > p.hairpin_depth_px) & ~along
    reason[off] = "gyro_mismatch"
    reason[deep] = "hairpin"
    ok &= ~(off | deep)
    return ok, reason


def check_frames(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
    p: SourceParams,
) -> int:
    """Apply the check to the ``covered`` frames' ``quality`` in place; returns how many
    frames were checked (those with a prediction and enough ``quality_ok`` streaks)."""
    sub = [frames[k] for k in covered if frames[k].quality is not None]
    curves = predicted_curves(
        sub, [timings[k] for k in covered if frames[k].quality is not None], model
    )
    checked = 0
    for fs, c in zip(sub, curves, strict=True):
        if c is None or fs.quality is None:
            continue
        ok0 = np.asarray(fs.quality[2], bool)
        chk = check_frame(fs, c, ok0, np.asarray(model.camera.K, float))
        if np.all(np.isnan(chk.residual)) and not np.any(ok0):
            continue
        ok, reason = apply_check(fs, chk, p)
        q = list(fs.quality)
        q[2], q[4] = ok, reason
        fs.quality = tuple(q)
        checked += 1
    return checked
