"""Blur trajectories from gyro samples and a calibration (numpy face of blurtrack.geometry.kernels).

:class:`BlurModel` binds a :class:`~blurtrack.io.calibration.Calibration` and a
:class:`~blurtrack.geometry.gyro.GyroTrace` and evaluates the functions of
:mod:`blurtrack.geometry.kernels` on
numpy arrays: the same code the CasADi calibration differentiates. All times are on the camera
clock in seconds; pixels follow docs/conventions.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from blurtrack.errors import GeometryError
from blurtrack.geometry import heatmap
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.geometry.kernels import (
    DEFAULT_MAX_SUBSTEP_S,
    NUMPY_OPS,
    Mat3,
    constant_mat3,
    matvec3,
    n_substeps,
    omega_cam_fn,
    project_c,
    relative_rotation,
    relative_rotation_small_angle,
    rolling_endpoint_c,
    rolling_endpoint_np,
    transpose3,
    unproject_c,
    warp_c,
)
from blurtrack.geometry.ordered_track import ordered_point_track
from blurtrack.geometry.orientation_grid import GRID_STEP_S, OrientationGrid, orientation_grid

#: Motion models: exact rotation integration, or the source paper's per-axis small angles.
ROTATION_MODELS: dict[str, Callable[..., Mat3]] = {
    "exact": relative_rotation,
    "small_angle": relative_rotation_small_angle,
}


#: Fewest samples per track for which :meth:`BlurModel.point_track_ordered` composes the
#: rotation sample to sample: a track of a few samples (a streak's two ends) takes as many
#: exponentials either way, and the kernel has no prefix products to pay (measured when
#: detection's predictions used it: ordered, 2-sample tracks took 0.47 s of the session
#: calibration's 0.9 on a 150-frame ``dense`` session; a 17-sample curve was 8 % cheaper
#: ordered, a 65-sample one 2-4x). Detection's predictions now read
#: :meth:`BlurModel.orientation_grid` instead.
ORDERED_MIN_SAMPLES = 9


@dataclass(frozen=True)
class BlurModel:
    """The gyro-driven blur model of one recording.

    Args:
        calib: camera, camera–IMU rotation, time shift and gyro bias.
        gyro: measured angular velocity on the IMU clock.
        max_substep_s: longest rotation-integration sub-step.
        rotation_model: ``"exact"`` or ``"small_angle"`` (the paper's approximation).
        check_coverage: refuse times the gyro does not cover (default) instead of
            extrapolating with the end samples.
        gyro_upsample: cubic-spline resampling factor of the measured gyro
            (:data:`~blurtrack.geometry.gyro.GYRO_UPSAMPLE`, the calibration's; 1 = plain linear
            interpolation of the samples). ``model.gyro`` is the resampled trace.
    """

    calib: Calibration
    gyro: GyroTrace
    max_substep_s: float = DEFAULT_MAX_SUBSTEP_S
    rotation_model: str = "exact"
    check_coverage: bool = True
    gyro_upsample: int = GYRO_UPSAMPLE

    def __post_init__(self) -> None:
        if self.gyro_upsample > 1:
            object.__setattr__(self, "gyro", self.gyro.upsampled(self.gyro_upsample))
        M = self.calib.gyro_scale_matrix
        A = (
            self.calib.R_cam_imu
            if np.allclose(M, np.eye(3), atol=0, rtol=0)
            else self.calib.R_cam_imu @ np.linalg.inv(M)
        )
        object.__setattr__(
            self,
            "_omega_fn",
            omega_cam_fn(
                self.gyro.omega_components,
                constant_mat3(A),
                tuple(self.calib.gyro_bias_radps),
                self.calib.timeshift_cam_imu_s,
            ),
        )
        if self.rotation_model not in ROTATION_MODELS:
            raise GeometryError(f"rotation_model must be one of {sorted(ROTATION_MODELS)}")
        if not self.max_substep_s > 0:
            raise GeometryError("max_substep_s must be positive")

    # ------------------------------------------------------------ internals
    @property
    def camera(self):
        return self.calib.camera

    def omega_cam_at(self, t_cam_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera-frame ω (rad/s) at camera times, as a component tuple."""
        return self._omega_fn(np.asarray(t_cam_s, dtype=float))  # type: ignore[attr-defined]

    def _check(self, *times: np.ndarray) -> None:
        """Raise :class:`CoverageError` unless the gyro covers every time given (camera clock;
        no times, nothing to cover)."""
        times = tuple(t for t in times if np.size(t))
        if not self.check_coverage or not times:
            return
        lo = min(float(np.min(t)) for t in times)
        hi = max(float(np.max(t)) for t in times)
        shift = self.calib.timeshift_cam_imu_s
        self.gyro.check_coverage(lo + shift, hi + shift)

    def _nsub(self, t_from: np.ndarray, t_to: np.ndarray) -> int:
        span = float(np.max(np.abs(np.asarray(t_to) - np.asarray(t_from)), initial=0.0))
        return n_substeps(span, self.max_substep_s)

    # --------------------------------------------------------------- public
    def rotations(self, t_from_s: np.ndarray, t_to_s: np.ndarray) -> np.ndarray:
        """Relative rotations ``R_c(t_from)^T R_c(t_to)`` as ``(N, 3, 3)``."""
        t0, t1 = np.broadcast_arrays(np.asarray(t_from_s, float), np.asarray(t_to_s, float))
        t0, t1 = t0.reshape(-1), t1.reshape(-1)
        self._check(t0, t1)
        R = ROTATION_MODELS[self.rotation_model](
            t0, t1, self.omega_cam_at, self._nsub(t0, t1), NUMPY_OPS
        )
        return np.stack(R, axis=-1).reshape(-1, 3, 3)

    def warp(self, pixels: np.ndarray, t_from_s: np.ndarray, t_to_s: np.ndarray) -> np.ndarray:
        """Where static directions seen at ``pixels (N, 2)`` at ``t_from`` are seen at ``t_to``.

        Times ``(N,)`` or scalars, camera clock, seconds. Returns ``(N, 2)`` pixels.
        """
        px = _pixels(pixels)
        t0, t1 = np.broadcast_arrays(np.asarray(t_from_s, float), np.asarray(t_to_s, float))
        t0 = np.broadcast_to(t0, px.shape[:1]).astype(float)
        t1 = np.broadcast_to(t1, px.shape[:1]).astype(float)
        self._check(t0, t1)
        cam = self.camera
        u, v = warp_c(
            px[:, 0],
            px[:, 1],
            t0,
            t1,
            self.omega_cam_at,
            cam.intrinsics,
            cam.dist,
            self._nsub(t0, t1),
            NUMPY_OPS,
            ROTATION_MODELS[self.rotation_model],
        )
        return np.stack([u, v], axis=1)

    def point_track(
        self, pixels: np.ndarray, t_ref_s: np.ndarray, times_s: np.ndarray
    ) -> np.ndarray:
        """Image positions ``(N, T, 2)`` at ``times_s (N, T)`` of points seen at ``pixels (N, 2)``
        at ``t_ref_s (N,)``."""
        px = _pixels(pixels)
        times = np.asarray(times_s, dtype=float)
        if times.ndim == 1:
            times = np.broadcast_to(times, (px.shape[0], times.size))
        n, t = times.shape
        tref = np.broadcast_to(np.asarray(t_ref_s, float), (n,))
        flat = self.warp(np.repeat(px, t, axis=0), np.repeat(tref, t), times.reshape(-1))
        return flat.reshape(n, t, 2)

    def point_track_ordered(
        self, pixels: np.ndarray, t_ref_s: np.ndarray, times_s: np.ndarray
    ) -> np.ndarray:
        """:meth:`point_track` for times ``(N, T)`` non-decreasing along each row, integrated
        sample to sample (:mod:`blurtrack.geometry.ordered_track`: one rotation exponential per
        sample instead of a whole integration each; the ``small_angle`` model, times out of
        order and tracks of fewer than :data:`ORDERED_MIN_SAMPLES` samples take
        :meth:`point_track`)."""
        px = _pixels(pixels)
        times = np.asarray(times_s, dtype=float)
        if times.ndim == 1:
            times = np.broadcast_to(times, (px.shape[0], times.size))
        tref = np.broadcast_to(np.asarray(t_ref_s, float), (px.shape[0],))
        if (
            self.rotation_model != "exact"
            or times.shape[1] < ORDERED_MIN_SAMPLES
            or np.any(np.diff(times, axis=1) < 0)
        ):
            return self.point_track(px, tref, times)
        self._check(tref, times)
        cam = self.camera
        return ordered_point_track(
            px, tref, times, self.omega_cam_at, cam.intrinsics, cam.dist, self.max_substep_s
        )

    def orientation_grid(
        self, lo_s: np.ndarray, hi_s: np.ndarray, step_s: float = GRID_STEP_S
    ) -> OrientationGrid:
        """The camera's orientation tabulated over the windows ``[lo_s, hi_s]`` (camera clock,
        seconds, ``(W,)`` each; :mod:`blurtrack.geometry.orientation_grid`), on a grid of
        ``step_s`` or the model's sub-step where finer. Its ``point_track`` reads tracks of any
        length and order in a window. Exact rotation model only (the ``small_angle`` model sums
        angles from each reference, no orientation to tabulate: :class:`GeometryError`)."""
        if self.rotation_model != "exact":
            raise GeometryError(f"no orientation grid for the {self.rotation_model} model")
        lo = np.asarray(lo_s, float).reshape(-1)
        hi = np.asarray(hi_s, float).reshape(-1)
        self._check(lo, hi)
        return orientation_grid(lo, hi, self.omega_cam_at, min(step_s, self.max_substep_s))

    def streak_endpoints(
        self,
        pixels_ref: np.ndarray,
        t_ref_s: float | np.ndarray,
        frame_t_s: float | np.ndarray,
        exposure_s: float | np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Start and end of the streaks of points seen at ``pixels_ref (N, 2)`` at ``t_ref_s``.

        The start is where the point is when its own row starts exposing (rolling shutter
        solved by fixed-point iteration), the end when that row stops.

        Returns:
            ``start (N, 2), end (N, 2), t_start_s (N,), t_end_s (N,)`` (camera clock).
        """
        px = _pixels(pixels_ref)
        n = px.shape[0]
        tref = np.broadcast_to(np.asarray(t_ref_s, float), (n,)).astype(float)
        ft = np.broadcast_to(np.asarray(frame_t_s, float), (n,)).astype(float)
        exp = np.broadcast_to(np.asarray(exposure_s, float), (n,)).astype(float)
        cam = self.camera
        span_lo, span_hi = ft, ft + cam.readout_s + exp
        self._check(span_lo, span_hi, tref)
        nsub = n_substeps(
            float(np.max(np.maximum(np.abs(span_hi - tref), np.abs(tref - span_lo)), initial=0.0)),
            self.max_substep_s,
        )
        # Both ends in one call (start: the row's start of exposure; end: its end); the exact
        # model carries the rotation through the row-time iteration.
        solve = (
            partial(rolling_endpoint_np, max_substep_s=self.max_substep_s)
            if self.rotation_model == "exact"
            else partial(
                rolling_endpoint_c, ops=NUMPY_OPS, rotation=ROTATION_MODELS[self.rotation_model]
            )
        )
        u, v, t = solve(
            np.concatenate([px[:, 0], px[:, 0]]),
            np.concatenate([px[:, 1], px[:, 1]]),
            np.concatenate([tref, tref]),
            np.concatenate([ft, ft]),
            np.concatenate([0.0 * exp, exp]),
            cam.readout_s,
            cam.height,
            self.omega_cam_at,
            cam.intrinsics,
            cam.dist,
            nsub,
        )
        uv = np.stack([u, v], axis=1)
        return uv[:n], uv[n:], t[:n], t[n:]

    def default_reference_time(self, frame_t_s: float, exposure_s: float) -> float:
        """Mid-exposure of the centre row: the default time of the sharp reference image."""
        cam = self.camera
        return float(frame_t_s + cam.readout_s * (cam.height - 1) / 2 / cam.height + exposure_s / 2)

    def heat_maps(
        self,
        frame_t_s: float,
        exposure_s: float,
        n_t: int = 16,
        t_ref_s: float | None = None,
        stride: int = 1,
        rows_per_chunk: int = 32,
    ) -> tuple[np.ndarray, np.ndarray]:
        """DESIGN heat maps of one frame: ``(6, H, W)`` float32 and Bézier fit error ``(H, W)``.

        ``q(τ)`` of pixel ``x`` in row ``r`` is ``warp(x, t_r + τ·exposure, t_ref) - x`` with
        ``t_r`` the row's start of exposure, sampled at ``n_t`` values of τ from 0 to 1.
        With ``stride > 1`` the maps are evaluated on every ``stride``-th row and column (plus
        the last) and interpolated bilinearly: trajectories vary smoothly across the image.
        """
        if n_t < 3:
            raise GeometryError("heat maps need n_t >= 3 trajectory samples")
        if stride < 1:
            raise GeometryError("stride must be >= 1")
        cam = self.camera
        W, H = cam.resolution
        t_ref = (
            self.default_reference_time(frame_t_s, exposure_s)
            if t_ref_s is None
            else float(t_ref_s)
        )
        self._check(np.array([frame_t_s, frame_t_s + cam.readout_s + exposure_s, t_ref]))
        xs = _grid(W, stride)
        ys = _grid(H, stride)
        tau = np.linspace(0.0, 1.0, n_t)
        rays_x, rays_y, _ = unproject_c(xs[None, :], ys[:, None], cam.intrinsics, cam.dist)
        rays_x = np.broadcast_to(rays_x, (ys.size, xs.size))
        rays_y = np.broadcast_to(rays_y, (ys.size, xs.size))
        nsub = n_substeps(
            max(abs(t_ref - frame_t_s), abs(frame_t_s + cam.readout_s + exposure_s - t_ref)),
            self.max_substep_s,
        )
        rot = ROTATION_MODELS[self.rotation_model]
        maps = np.empty((6, ys.size, xs.size), dtype=np.float32)
        err = np.empty((ys.size, xs.size))
        for r0 in range(0, ys.size, rows_per_chunk):
            rows = ys[r0 : r0 + rows_per_chunk]
            t = cam.row_start_s(frame_t_s, rows)[:, None] + exposure_s * tau[None, :]
            # R_c(t)^T R_c(t_ref): rotation taking the view at t to the view at t_ref.
            R: Sequence[Any] = rot(
                t.reshape(-1), np.full(t.size, t_ref), self.omega_cam_at, nsub, NUMPY_OPS
            )
            R = [c.reshape(rows.size, 1, n_t) for c in R]
            rx = rays_x[r0 : r0 + rows.size, :, None]
            ry = rays_y[r0 : r0 + rows.size, :, None]
            X, Y, Z = matvec3(transpose3(tuple(R)), (rx, ry, 1.0 + 0 * rx))
            u, v = project_c(X, Y, Z, cam.intrinsics, cam.dist)
            q = np.stack([u - xs[None, :, None], v - rows[:, None, None]], axis=-1)
            m, e = heatmap.pack(q, tau)
            maps[:, r0 : r0 + rows.size] = m
            err[r0 : r0 + rows.size] = e
        if stride > 1:
            up = _upsample(np.concatenate([maps, err[None].astype(np.float32)]), xs, ys, W, H)
            maps, err = up[:6], up[6].astype(float)
        return maps, err


def _pixels(pixels: np.ndarray) -> np.ndarray:
    px = np.asarray(pixels, dtype=float)
    if px.ndim != 2 or px.shape[1] != 2:
        raise GeometryError(f"pixels must have shape (N, 2), got {px.shape}")
    return px


def _grid(n: int, stride: int) -> np.ndarray:
    g = np.arange(0, n, stride, dtype=float)
    return g if g[-1] == n - 1 else np.append(g, n - 1)


def _interp_index(grid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """For every ``x = 0..n-1``: the grid cell ``i`` holding it and its fraction ``f`` in it,
    so that linear interpolation is ``(1 - f) a[i] + f a[i + 1]``."""
    x = np.arange(n, dtype=float)
    i = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    return i, (x - grid[i]) / (grid[i + 1] - grid[i])


def _upsample(a: np.ndarray, xs: np.ndarray, ys: np.ndarray, W: int, H: int) -> np.ndarray:
    """Bilinear interpolation of grid values ``a (C, len(ys), len(xs))`` to every pixel
    ``(C, H, W)`` float32.

    Separable and written out by hand (numpy has no strided-grid interpolation; the dense
    matrix product it replaces is 3-20x slower depending on the BLAS threads): along x on the
    small grid, then per row cell one fused ``lo + g * (hi - lo)`` pass over the output.
    """
    a = np.asarray(a, np.float32)
    if xs.size < 2 or ys.size < 2:
        return np.broadcast_to(a.mean(axis=(1, 2), keepdims=True), (a.shape[0], H, W)).copy()
    i, f = _interp_index(xs, W)
    lo = a[:, :, i]
    rows = lo + f.astype(np.float32) * (a[:, :, i + 1] - lo)  # (C, len(ys), W)
    step = np.diff(rows, axis=1)
    j, g = _interp_index(ys, H)
    g = g.astype(np.float32)[:, None]
    out = np.empty((a.shape[0], H, W), np.float32)
    starts = np.searchsorted(j, np.arange(ys.size - 1), side="left")
    ends = np.searchsorted(j, np.arange(ys.size - 1), side="right")
    for k, (r0, r1) in enumerate(zip(starts, ends, strict=True)):
        if r1 > r0:
            block = out[:, r0:r1]
            np.multiply(g[r0:r1], step[:, k, None, :], out=block)
            block += rows[:, k, None, :]
    return out
