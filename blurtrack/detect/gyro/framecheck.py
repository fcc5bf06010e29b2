"""The gyro's check of one frame's ``quality_ok`` ends: each streak's start-to-end vector
against its prediction (:func:`vector_residual`, or the session's corrected prediction,
:func:`blurtrack.detect.gyro.gyrotrust.check_frames`), how far its predicted path turns
beyond an end (:func:`hairpin_depth`), the frame's own tolerances (:func:`frame_tolerances`)
and the verdict (:func:`apply_check`). Why each test holds, and how a session's frames are
predicted and checked: :mod:`blurtrack.detect.gyro.gyrotrust`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.sessioncalib import FIT_ROUNDS
from blurtrack.detect.params import SourceParams

#: Fewest ``quality_ok`` streaks in a frame for its similarity fit (as the shape consensus).
MIN_VOTERS = 5


@dataclass(frozen=True)
class GyroCheck:
    """Per streak of a frame: ``residual`` (px, NaN: not checked), ``depth`` (px)."""

    residual: np.ndarray
    depth: np.ndarray


def hairpin_depth(pts: np.ndarray) -> np.ndarray:
    """``(N,)`` how far the start and end of curves ``pts (N, S, 2)`` lie from the curve's
    extremities along its chord, where the image's line ends: the distance from the start to
    the sample that lies furthest back along the chord, and from the end to the one furthest
    on (the larger of the two; 0 for a path that never doubles back along its chord). A curve
    that returns to its start (no chord) is measured along its principal axis."""
    if pts.shape[0] == 0:
        return np.zeros(0)
    chord = pts[:, -1] - pts[:, 0]
    L = np.hypot(*chord.T)
    small = L < 1e-6
    u = chord / np.where(small, 1.0, L)[:, None]
    if small.any():  # the principal axis, of those curves only
        c = pts[small] - pts[small].mean(axis=1, keepdims=True)
        _, vecs = np.linalg.eigh(np.einsum("nsi,nsj->nij", c, c))
        u[small] = vecs[:, :, -1]
    proj = np.einsum("nsk,nk->ns", pts, u)
    # The distance from each end to the path's extremity beyond it along the chord, where the
    # image's line ends: a hook that turns sideways puts that point off the chord too.
    rows = np.arange(pts.shape[0])
    d0 = np.hypot(*(pts[:, 0] - pts[rows, np.argmin(proj, axis=1)]).T)
    d1 = np.hypot(*(pts[:, -1] - pts[rows, np.argmax(proj, axis=1)]).T)
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


def check_frame(fs: FrameStreaks, curves: np.ndarray, ok: np.ndarray) -> GyroCheck:
    """The :class:`GyroCheck` of one frame's streaks against their predicted ``curves``, the
    frame's similarity fitted over the streaks ``ok`` (the fallback of
    :func:`~blurtrack.detect.gyro.gyrotrust.check_frames`
    where the session's fit does not apply)."""
    m = fs.end_b - fs.end_a
    p = curves[:, -1] - curves[:, 0]
    return GyroCheck(vector_residual(m, p, ok), hairpin_depth(curves))


class FrameTolerance(NamedTuple):
    """One frame's tolerances of the check (px; :func:`frame_tolerances`) and the model error
    they follow (px; NaN: the frame has no checked ``quality_ok`` streak to measure it)."""

    vector_px: float
    confirm_px: float
    model_error_px: float


def frame_tolerances(
    residual: np.ndarray, ok: np.ndarray, depth: np.ndarray, p: SourceParams
) -> FrameTolerance:
    """One frame's vector and confirmation tolerances (px): ``p.gyro_vector_tol_px`` and
    ``p.gyro_confirm_tol_px`` where the prediction is right, lower where the frame's model
    is off.

    ``residual``, ``ok``, ``depth`` ``(N,)``: the check's vector residuals (px, NaN: not
    checked), the image's ``quality_ok`` before the check, the predicted hairpin depths (px).
    The frame's model error is the median residual of its *plain* streaks (``ok``, checked,
    not turning beyond an end: their ends are the image's edges; where fewer than
    :data:`MIN_VOTERS`, every ``ok`` checked streak) less their own ends' typical share
    ``p.plain_end_px``. A streak whose vector is ``r`` from a prediction that is off by that
    much may have an end off by ``r`` plus it, so the vector tolerance is ``p.end_gate_px``
    less the model error, at most ``p.gyro_vector_tol_px``; the confirmation tolerance keeps
    its margin below it. A streak the gyro-template pass placed along a curve that hooks has
    its ends where the curve says; its residual is small by construction, and only this
    bound sees the frame's model off (``hard_long_exposure`` 101: 17 wrong ``quality_ok``
    of 360 at the session's tolerances, their residuals 0.5-1.4 px, in frames whose plain
    residuals are 1.3-1.9 px at the median; docs/detection.md "Trust")."""
    checked = ok & np.isfinite(residual)
    plain = checked & (depth <= p.hairpin_depth_px)
    use = plain if int(plain.sum()) >= MIN_VOTERS else checked
    if not use.any():
        return FrameTolerance(p.gyro_vector_tol_px, p.gyro_confirm_tol_px, float("nan"))
    model_px = float(np.median(residual[use])) - p.plain_end_px
    return tolerances_for(model_px, p)


def tolerances_for(model_error_px: float, p: SourceParams) -> FrameTolerance:
    """The tolerances of a frame whose prediction is off by ``model_error_px`` (px): the
    vector's ``p.end_gate_px`` less it, at most ``p.gyro_vector_tol_px``; the confirmation's
    as much below it as ``p.gyro_confirm_tol_px`` is below ``p.gyro_vector_tol_px``."""
    vector = min(p.gyro_vector_tol_px, p.end_gate_px - model_error_px)
    confirm = min(p.gyro_confirm_tol_px, vector - (p.gyro_vector_tol_px - p.gyro_confirm_tol_px))
    return FrameTolerance(vector, confirm, model_error_px)


def apply_check(
    fs: FrameStreaks,
    check: GyroCheck,
    p: SourceParams,
    tolerance: FrameTolerance | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``fs.quality``'s ``quality_ok`` and ``reason`` after the check: the ``quality_ok``
    streaks that fail it demoted (``hairpin`` first, then ``gyro_mismatch``), the streaks
    with one image doubt (:attr:`~blurtrack.detect.frame.FrameStreaks.one_doubt`: one lit
    end, a blown-out core or a shape off the consensus, with or without a crossing; or a
    crossing alone) whose vector is within the confirmation tolerance and whose path does not
    turn beyond an end confirmed (``ok``: the gyro measured the start-to-end vector the image
    doubted); other streaks keep their image reason. ``tolerance``: the frame's
    (:func:`frame_tolerances`; None: ``p.gyro_vector_tol_px`` and ``p.gyro_confirm_tol_px``)."""
    assert fs.quality is not None
    if tolerance is None:
        vector_tol, confirm_tol = p.gyro_vector_tol_px, p.gyro_confirm_tol_px
    else:
        vector_tol, confirm_tol = tolerance.vector_px, tolerance.confirm_px
    ok = np.asarray(fs.quality[2], bool).copy()
    reason = np.asarray(fs.quality[4], object).copy()
    along = fs.along_curve if len(fs.along_curve) == len(fs) else np.zeros(len(fs), bool)
    single = fs.one_doubt if len(fs.one_doubt) == len(fs) else np.zeros(len(fs), bool)
    with np.errstate(invalid="ignore"):  # NaN: not checked (neither off nor confirmed)
        fits = check.residual <= confirm_tol
        off = ok & (check.residual > vector_tol)
        turns = (check.depth > p.hairpin_depth_px) & ~along
    deep = ok & turns
    confirmed = single & ~ok & fits & ~turns
    reason[off] = "gyro_mismatch"
    reason[deep] = "hairpin"
    reason[confirmed] = "ok"
    ok = (ok & ~(off | deep)) | confirmed
    return ok, reason
