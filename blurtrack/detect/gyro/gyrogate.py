"""The gyro-template pass's gate (:mod:`blurtrack.detect.gyro.gyropass`): which frames the pass
refines, from their first-pass streaks and the blur model's predicted curves alone (one model
call per frame, no image work), and why
(:data:`~blurtrack.detect.gyro.gyrocandidates.GateReason`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.framecheck import hairpin_depth
from blurtrack.detect.gyro.gyrocandidates import GateReason, inside_frame
from blurtrack.detect.gyro.gyroconfirm import mismatch
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.params import GyroPassParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import CoverageError

#: Samples of the gate's predicted curves (odd: its middle sample is the mid-exposure one, as
#: at :data:`~blurtrack.detect.gyro.gyrocurve.CURVE_SAMPLES`; the gate is most of the pass's cost
#: on frames it lets through to nothing, ``dense``: 13 ms per frame at 65 samples).
GATE_SAMPLES = 17


def gate(
    fs: FrameStreaks,
    timing: FrameTiming,
    model: Any,
    gp: GyroPassParams,
    curves_out: list[np.ndarray] | None = None,
    hook_depth_px: float | None = None,
    vector_tol_px: float | None = None,
) -> GateReason | None:
    """Whether the pass has work on a frame, from its first-pass streaks alone (one model
    call, no image work): None where it has none (no streak inside the frame, none long, the
    gyro not covering it, or every long streak matching its prediction and few hooking in a
    frame that is not a hairpin frame), else why it has (:data:`GateReason`). ``gp``: the
    pass's parameters.
    ``curves_out``: gets the predicted curves ``(n_inside, GATE_SAMPLES, 2)`` of the streaks
    inside the frame, where the model predicts them (the gyro check's, for a frame the pass
    leaves as it was). ``hook_depth_px``: the check's hairpin depth (``source.hairpin_depth_px``;
    None: frames are not let through for their hooks, ``gp.hook_fraction``).
    ``vector_tol_px``: where ``model`` is the session's corrected one, the check's vector
    tolerance (``source.gyro_vector_tol_px``): with ``gp.time_law``, frames are let through
    where more than ``gp.hook_fraction`` of the long streaks' vectors miss by more (None: not
    tested)."""
    inside = inside_frame(fs)
    if not inside.any():
        return None
    # On the first pass's midpoints, with curves of GATE_SAMPLES: the ends and the midpoint
    # are the same samples as at full sampling, the arc a polyline of fewer points.
    try:
        curves = predict_curves(
            model, fs.time_mid[inside], timing.t_s, timing.exposure_s, GATE_SAMPLES
        )
    except CoverageError:
        return None
    if curves_out is not None:
        curves_out.append(curves.pts)
    g_long = curves.arc >= gp.min_arc_px
    if not g_long.any():
        return None
    if float(np.median(curves.chord[g_long] / curves.arc[g_long])) < gp.hairpin_chord:
        return "hairpin"
    # Streaks the first pass measured far from the prediction (placed at their time
    # midpoints): chains and fragments of long streaks.
    mid = curves.pts.shape[1] // 2
    g_pts = curves.pts - curves.pts[:, mid, None] + fs.time_mid[inside, None]
    a, b = fs.end_a[inside], fs.end_b[inside]
    bad = mismatch(a, b, g_pts[:, 0], g_pts[:, -1]) > gp.tol_px + gp.tol_rel * curves.arc
    if float(np.mean(bad[g_long])) > gp.bad_fraction:
        return "mismatch"
    if _hooked(curves.pts[g_long], hook_depth_px, gp.hook_fraction):
        return "hooks"
    if vector_tol_px is not None and gp.time_law:  # the pass measures them under their laws
        off = vectors_missed(fs, curves.pts, vector_tol_px)[inside]
        if float(np.mean(off[g_long])) > gp.hook_fraction:
            return "vectors"
    return None


def vectors_missed(fs: FrameStreaks, pts: np.ndarray, tol_px: float) -> np.ndarray:
    """``(len(fs),)`` bool: the streaks inside the frame whose start-to-end vectors miss their
    predicted curves ``pts (n_inside, S, 2)`` (the gate's) by more than ``tol_px``
    (:func:`vector_residual`)."""
    inside = inside_frame(fs)
    off = np.zeros(len(fs), bool)
    off[inside] = vector_residual(fs.end_a[inside], fs.end_b[inside], pts) > tol_px
    return off


def vector_residual(a: np.ndarray, b: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Orientation-free distance (px) of the measured vectors ``b - a`` from the predicted
    curves' start-to-end vectors (``pts (N, S, 2)``): the gyro check's residual where the
    model is the session's corrected one."""
    m, p = b - a, pts[:, -1] - pts[:, 0]
    return np.asarray(np.minimum(np.hypot(*(m - p).T), np.hypot(*(m + p).T)))


def _hooked(pts: np.ndarray, depth_px: float | None, fraction: float) -> bool:
    """Whether more than ``fraction`` of the curves ``pts (N, S, 2)`` hook or double back by
    more than ``depth_px`` (:func:`~blurtrack.detect.gyro.framecheck.hairpin_depth`; None: no)."""
    if depth_px is None or pts.shape[0] == 0:
        return False
    return float(np.mean(hairpin_depth(pts) > depth_px)) > fraction
