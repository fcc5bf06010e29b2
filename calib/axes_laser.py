"""Axis discovery on laser sessions: streak time midpoints carried to the next frame.

Laser dots form a regular grid, and between frames the grid can move by more than half its
spacing, so dots cannot be paired from the images alone without aliasing by a grid cell. Each
candidate mapping ``P`` (and time shift) instead carries every midpoint ``m`` of frame ``a``
to frame ``a + 1`` with the gyro's rotation over the midpoint's own interval
(``t_m = T + exposure / 2 + readout · ȳ / H``, the same row in the next frame; DESIGN's
rolling shutter) and scores the median distance to the nearest midpoint there, capped at a
third of the dots' spacing: under the true mapping the prediction lands on the same dot
(sub-pixel), under a wrong one anywhere in the grid (about a quarter of the spacing). The
scan, ranking and refusals are :mod:`calib.axes`'s.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from calib.axes import (
    MIN_PAIRS,
    MIN_POINTS,
    AxisSearch,
    AxisSearchError,
    gyro_rotations,
    proper_axis_permutations,
    ranked,
    scan_candidates,
)

#: Midpoints scored per candidate (a deterministic subsample beyond that).
MAX_POINTS = 1500
#: Frames are kept apart in one k-d tree by this row offset per frame index (px).
FRAME_STRIDE_PX = 1.0e5


def search_axes_laser(
    mid: np.ndarray,
    rows: np.ndarray,
    frame: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    camera: Camera,
    gyro: GyroTrace,
    shift0_s: float,
    window_s: float,
) -> AxisSearch:
    """Score the 24 proper axis permutations on midpoints (see the module docstring).

    Args:
        mid: ``(N, 2)`` streak time midpoints (px); ``rows``: ``(N,)`` rows dating them;
            ``frame``, ``frame_t_s``, ``exposure_s``: ``(N,)`` per streak, times relative to
            the gyro trace's origin (camera clock).
    """
    frame = np.asarray(frame, np.int64)
    nxt = np.isin(frame + 1, frame)
    counts = np.bincount(frame[nxt]) if np.any(nxt) else np.zeros(0, np.int64)
    pairs = np.flatnonzero(counts >= MIN_POINTS)
    src = np.flatnonzero(np.isin(frame, pairs))
    H = camera.height
    first = {int(f): i for f, i in zip(frame[::-1], np.arange(frame.size)[::-1], strict=True)}
    nb = np.array([first[int(f) + 1] for f in frame[src]], dtype=np.int64)
    # A midpoint's time, and that of the same row in the next frame (that frame's timing).
    ta = frame_t_s[src] + exposure_s[src] / 2 + camera.readout_s * rows[src] / H
    t_b = frame_t_s[nb] + exposure_s[nb] / 2 + camera.readout_s * rows[src] / H
    g = gyro.upsampled(GYRO_UPSAMPLE)
    ok = np.array(
        [
            g.covers(a + shift0_s - window_s, b + shift0_s + window_s)
            for a, b in zip(ta.tolist(), t_b.tolist(), strict=True)
        ],
        dtype=bool,
    )
    src, ta, t_b = src[ok], ta[ok], t_b[ok]
    n_pairs = np.unique(frame[src]).size
    if n_pairs < MIN_PAIRS:
        raise AxisSearchError(
            f"too few consecutive frame pairs with {MIN_POINTS}+ laser midpoints that the gyro "
            f"covers (± {window_s * 1e3:.0f} ms shift search): {n_pairs}, need {MIN_PAIRS}"
        )
    if src.size > MAX_POINTS:
        keep = np.sort(np.random.default_rng(0).choice(src.size, MAX_POINTS, replace=False))
        src, ta, t_b = src[keep], ta[keep], t_b[keep]
    tree = cKDTree(np.stack([mid[:, 0], mid[:, 1] + FRAME_STRIDE_PX * frame], axis=1))
    own = np.stack([mid[:, 0], mid[:, 1] + FRAME_STRIDE_PX * frame], axis=1)
    spacing = float(np.median(tree.query(own, k=2)[0][:, 1]))
    cap = spacing / 3
    bearings = camera.unproject(mid[src])
    target_off = FRAME_STRIDE_PX * (frame[src] + 1)
    P = proper_axis_permutations()

    def predict(shift: float, which: np.ndarray) -> np.ndarray:
        Mt = np.swapaxes(gyro_rotations(g, ta, t_b, shift), 1, 2)
        R = np.einsum("cij,njl,cml->cnim", P[which], Mt, P[which])  # P Mᵀ Pᵀ per point
        X = np.einsum("cnij,nj->cni", R, bearings)
        return np.stack([X[..., 0] / X[..., 2], X[..., 1] / X[..., 2]], axis=-1)

    def project(X: np.ndarray) -> np.ndarray:
        flat = X.reshape(-1, 2)
        px = camera.project(np.column_stack([flat, np.ones(len(flat))]))
        return px.reshape(X.shape)

    def score(shift: float, which: np.ndarray) -> np.ndarray:
        q = project(predict(shift, which))
        d, _ = tree.query(
            np.stack([q[..., 0], q[..., 1] + target_off], axis=-1).reshape(-1, 2),
            distance_upper_bound=cap,
        )
        return np.median(np.minimum(d, cap).reshape(which.size, -1), axis=1)

    shifts, scores = scan_candidates(score, shift0_s, window_s)
    best = int(np.argmin(scores))
    q = project(predict(float(shifts[best]), np.array([best])))[0]
    motion = float(np.median(np.linalg.norm(q - mid[src], axis=1)))
    return ranked(shifts, scores, motion, int(n_pairs), "laser midpoints")
