"""The camera's orientation tabulated on a fine time grid, and point tracks read from it.

Every streak of a frame is drawn under the same rotation ``R_c(t)``; only its row's times
differ. :func:`orientation_grid` integrates the rotation once per time window (a frame's
readout and exposure) on a grid of ``step_s``, with the midpoint Lie-group integrator of
:mod:`blurtrack.geometry.kernels` (one exponential per grid step, the steps composed by a
log-depth prefix product), and :meth:`OrientationGrid.point_track` reads any sample time from
it by linear interpolation between the two grid orientations around it.

Why interpolating matrices is exact enough: a point's direction at ``t`` is ``R_c(t)^T v``, and
blending two orientations ``theta = |omega| step`` apart blends two rotated directions. The
blend leaves the chord of the arc between them: its length falls short by ``O(theta^2)``, which
the perspective division removes, and its direction differs from the arc's by ``O(theta^3)``
(about ``1e-12`` rad at 10 rad/s and :data:`GRID_STEP_S`). What remains is the midpoint rule's
own error on the grid; against a converged integration on a shaking test gyro it is ``1e-4`` px
at :data:`GRID_STEP_S` (``tests/blurtrack/geometry/test_geometry_orientation_grid.py``).

Cost: a track of ``T`` samples costs two gathers and a blend per sample, against one rotation
exponential and one prefix product per sample for
:func:`~blurtrack.geometry.ordered_track.ordered_point_track`; a window's grid costs one
exponential per step once. The detection's predicted curves of one frame (300 streaks of 17
samples, three rolling-shutter iterations) take 1.5 ms instead of 3.8.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blurtrack.errors import GeometryError
from blurtrack.geometry.kernels import NUMPY_OPS, OmegaFn, project_c, so3_exp_c, unproject_c

#: Grid step (s) of :func:`orientation_grid` for detection's curves: the midpoint rule's error
#: on it is about 1e-4 px for hand shake (the 4 ms sub-steps of the detection models' ordered
#: tracks: 7e-3 px, with the gyro interpolated linearly between its samples).
GRID_STEP_S = 1.25e-4


@dataclass(frozen=True)
class OrientationGrid:
    """``R_c(lo_s[w])^T R_c(lo_s[w] + j * step_s)`` as row-major 9-vectors ``P (W, M + 1, 9)``:
    the orientation in window ``w`` at grid point ``j`` relative to the window's start
    (camera clock, seconds; ``lo_s (W,)``)."""

    lo_s: np.ndarray
    step_s: float
    P: np.ndarray

    def rotations(self, t_s: np.ndarray, window: np.ndarray) -> np.ndarray:
        """``(..., 9)`` orientations at times ``t_s`` (any shape) in the windows ``window``
        (window indices broadcasting against ``t_s``), blended linearly between the two grid
        points around each time (times outside a window take its end orientations' blend
        clamped to the grid)."""
        M = self.P.shape[1] - 1
        x = (t_s - self.lo_s[window]) / self.step_s
        j = np.clip(np.floor(x).astype(np.int64), 0, M - 1)
        a = np.clip(x - j, 0.0, 1.0)[..., None]
        flat = self.P.reshape(-1, 9)
        k = window * (M + 1) + j
        return flat[k] * (1.0 - a) + flat[k + 1] * a

    def point_track(
        self,
        pixels: np.ndarray,
        t_ref_s: np.ndarray,
        times_s: np.ndarray,
        window: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        dist: tuple[float, ...],
    ) -> np.ndarray:
        """Image positions of static directions seen at ``pixels (N, 2)`` at ``t_ref_s (N,)``,
        at ``times_s (N, T)`` (any order), each point's times in its window ``window (N,)``
        (ints): ``(N, T, 2)`` pixels, ``pi(K R_c(t)^T R_c(t_ref) K^-1 x)`` as
        :func:`~blurtrack.geometry.kernels.warp_c`. ``intrinsics``, ``dist``: the camera's
        ``(fx, fy, cx, cy)`` and radtan coefficients. :meth:`directions` then
        :meth:`track_directions` (the directions kept where the same points are tracked at
        other times)."""
        v = self.directions(pixels, t_ref_s, window, intrinsics, dist)
        return self.track_directions(v, times_s, window, intrinsics, dist)

    def directions(
        self,
        pixels: np.ndarray,
        t_ref_s: np.ndarray,
        window: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        dist: tuple[float, ...],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The world directions (relative to each window's start) of the points seen at
        ``pixels (N, 2)`` at ``t_ref_s (N,)`` in the windows ``window (N,)``: ``P_ref K^-1 x``,
        three ``(N, 1)`` components (:meth:`point_track`)."""
        px = np.asarray(pixels, float).reshape(-1, 2)
        w = np.asarray(window, np.int64).reshape(-1)
        rx, ry, rz = unproject_c(px[:, 0], px[:, 1], intrinsics, dist)
        R = self.rotations(np.asarray(t_ref_s, float).reshape(-1), w)
        v0 = (R[:, 0] * rx + R[:, 1] * ry + R[:, 2] * rz)[:, None]
        v1 = (R[:, 3] * rx + R[:, 4] * ry + R[:, 5] * rz)[:, None]
        v2 = (R[:, 6] * rx + R[:, 7] * ry + R[:, 8] * rz)[:, None]
        return v0, v1, v2

    def track_directions(
        self,
        v: tuple[np.ndarray, np.ndarray, np.ndarray],
        times_s: np.ndarray,
        window: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        dist: tuple[float, ...],
    ) -> np.ndarray:
        """``(N, T, 2)`` image positions at ``times_s (N, T)`` of the :meth:`directions` ``v``
        of points in the windows ``window (N,)``: ``pi(K P_t^T v)``."""
        v0, v1, v2 = v
        w = np.asarray(window, np.int64).reshape(-1)
        Q = self.rotations(np.asarray(times_s, float), w[:, None])
        X = Q[..., 0] * v0 + Q[..., 3] * v1 + Q[..., 6] * v2
        Y = Q[..., 1] * v0 + Q[..., 4] * v1 + Q[..., 7] * v2
        Z = Q[..., 2] * v0 + Q[..., 5] * v1 + Q[..., 8] * v2
        u, y = project_c(X, Y, Z, intrinsics, dist)
        return np.stack([u, y], axis=-1)


def orientation_grid(
    lo_s: np.ndarray, hi_s: np.ndarray, omega_cam_at: OmegaFn, step_s: float = GRID_STEP_S
) -> OrientationGrid:
    """The orientation on a grid of ``step_s`` over each window ``[lo_s[w], hi_s[w]]`` (camera
    clock, seconds, ``(W,)`` each; the grid reaches at least ``hi_s``, with as many steps in
    every window as the longest needs): midpoint steps ``exp(omega(t_j + step/2) step)``
    composed in order. ``omega_cam_at``: camera-frame angular velocity, rad/s."""
    lo = np.asarray(lo_s, float).reshape(-1)
    hi = np.asarray(hi_s, float).reshape(-1)
    if lo.shape != hi.shape or lo.size == 0:
        raise GeometryError(f"windows need matching non-empty starts and ends, got {lo.shape}")
    if not (step_s > 0 and np.all(np.isfinite(lo)) and np.all(hi >= lo)):
        raise GeometryError("windows need finite starts, ends not before them, a positive step")
    m = max(1, math.ceil(float(np.max(hi - lo)) / step_s - 1e-9))
    t_mid = lo[:, None] + (np.arange(m) + 0.5) * step_s  # (W, m)
    wx, wy, wz = (np.asarray(c, float).reshape(t_mid.shape) for c in omega_cam_at(t_mid.ravel()))
    steps = np.stack(so3_exp_c(wx * step_s, wy * step_s, wz * step_s, NUMPY_OPS), axis=-1)
    P = np.empty((lo.size, m + 1, 3, 3))
    P[:, 0] = np.eye(3)
    P[:, 1:] = steps.reshape(lo.size, m, 3, 3)
    # Inclusive prefix products P[j] = S_0 ... S_(j-1), by doubling (log2(m) batched products).
    d = 1
    while d <= m:
        P[:, d:] = P[:, :-d] @ P[:, d:]
        d *= 2
    return OrientationGrid(lo, float(step_s), P.reshape(lo.size, m + 1, 9))
