"""The calibration residual, built once from :mod:`blurtrack.geometry.kernels` for numpy and CasADi.

Residual of one streak (DESIGN's pure-rotation model, rolling shutter included): the measured
start ``s`` was seen when its row started exposing, ``t_s = frame_t + readout · s_y / H``; the
measured end ``e`` when its row stopped, ``t_e = frame_t + readout · e_y / H + exposure``.
Warping ``s`` from ``t_s`` to ``t_e`` with the gyro-driven model must land on ``e``::

    r = warp_c(s, t_s, t_e; theta) - e          (2 values per streak, pixels)

At the true parameters and noise-free endpoints ``r = 0`` exactly: the end satisfies the same
row-time equation that :func:`blurtrack.geometry.kernels.rolling_endpoint_c` solves by fixed-point
iteration, and this form needs a single warp per streak instead of five (see
docs/calibration.md). :func:`endpoint_residual` is evaluated on numpy arrays (initialisation,
outlier tests, hold-out statistics); the solver's residuals and Jacobians are those of the same
model on a fixed orientation grid (:mod:`calib.grid`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    Backend,
    Value,
    constant_mat3,
    matmul3,
    n_substeps,
    omega_cam_fn,
    row_start_c,
    so3_exp_c,
    warp_c,
)
from calib.data import StreakSet
from calib.params import LAYOUT, N_THETA, inverse3, scale_tuple


class CasadiBackend:
    """:class:`blurtrack.geometry.kernels.Backend` over CasADi symbols."""

    @staticmethod
    def sin(x: Value, /) -> Value:
        return ca.sin(x)

    @staticmethod
    def cos(x: Value, /) -> Value:
        return ca.cos(x)

    @staticmethod
    def sqrt(x: Value, /) -> Value:
        return ca.sqrt(x)


CA_OPS: Backend = CasadiBackend()


def _streak_motion(
    theta: Sequence[Any],
    cols: Sequence[Any],
    omega_imu_at: Callable[[Any], tuple],
    R0_cam_imu: np.ndarray,
    height: int,
    ops: Any,
) -> tuple:
    """Camera-frame ω function, intrinsics and the warp interval ``(t_s, t_e)`` of streaks."""
    L = LAYOUT
    shift, readout = theta[L["timeshift_s"]], theta[L["readout_s"]]
    fx, fy, cx, cy = (theta[i] for i in range(*L["intrinsics"].indices(N_THETA)))
    bias = tuple(theta[i] for i in range(*L["bias"].indices(N_THETA)))
    wx, wy, wz = (theta[i] for i in range(*L["rotation"].indices(N_THETA)))
    dR = so3_exp_c(wx, wy, wz, ops)
    # omega_cam = R (I + S)^-1 (w - b), the exact inverse (as BlurModel applies it).
    R = matmul3(matmul3(dR, constant_mat3(R0_cam_imu)), inverse3(scale_tuple(theta)))
    ft, exp, row_s, row_e = cols[4:8]
    t_s = row_start_c(ft, row_s, readout, height)
    t_e = row_start_c(ft, row_e, readout, height) + exp
    return omega_cam_fn(omega_imu_at, R, bias, shift), (fx, fy, cx, cy), t_s, t_e


def endpoint_residual(
    theta: Sequence[Any],
    cols: Sequence[Any],
    omega_imu_at: Callable[[Any], tuple],
    R0_cam_imu: np.ndarray,
    dist: Sequence[float],
    height: int,
    n_sub: int,
    ops: Any,
) -> tuple[Any, Any]:
    """Residual ``(r_x, r_y)`` of a batch of streaks (see the module docstring).

    Args:
        theta: the 18 parameters of :mod:`calib.params` (numbers or CasADi scalars).
        cols: ``(start_x, start_y, end_x, end_y, frame_t_s, exposure_s, row_s, row_e)``,
            arrays ``(N,)`` or CasADi columns; times on the camera clock, seconds; ``row_s``,
            ``row_e`` date the start and the end (a streak's own ``start_y``, ``end_y``).
        omega_imu_at: IMU-clock time -> ``(wx, wy, wz)`` measured rate, rad/s.
        R0_cam_imu: ``(3, 3)`` initial camera–IMU rotation, perturbed by the ``rotation`` block.
        dist: fixed radtan coefficients (``()`` for none).
        height: image height H in rows.
        n_sub: integration sub-steps per warp (fixed for a CasADi graph).
    """
    omega, K, t_s, t_e = _streak_motion(theta, cols, omega_imu_at, R0_cam_imu, height, ops)
    sx, sy, ex, ey = cols[0:4]
    u, v = warp_c(sx, sy, t_s, t_e, omega, K, tuple(dist), n_sub, ops)
    return u - ex, v - ey


def choose_substeps(
    streaks: StreakSet, height: int, readout_bound_s: float, max_substep_s: float = 1e-3
) -> int:
    """Sub-steps so that no streak's warp interval exceeds ``max_substep_s`` per step."""
    if len(streaks) == 0:
        return 1
    rows = streaks.rows
    dv = np.abs(rows[:, 1] - rows[:, 0]) / height
    span = float(np.max(streaks.exposure_s + readout_bound_s * dv))
    return n_substeps(span, max_substep_s)


def _columns(streaks: StreakSet) -> list[np.ndarray]:
    rows = streaks.rows
    return [
        streaks.start[:, 0],
        streaks.start[:, 1],
        streaks.end[:, 0],
        streaks.end[:, 1],
        streaks.frame_t_s,
        streaks.exposure_s,
        rows[:, 0],
        rows[:, 1],
    ]


@dataclass(frozen=True)
class ResidualModel:
    """Everything fixed while fitting: gyro, initial rotation, distortion, image height."""

    gyro: GyroTrace
    R0_cam_imu: np.ndarray
    dist: tuple[float, ...]
    height: int
    n_sub: int

    def residual_np(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """Residuals ``(N, 2)`` in pixels, evaluated with numpy."""
        rx, ry = endpoint_residual(
            list(np.asarray(theta, float)),
            _columns(streaks),
            self.gyro.omega_components,
            self.R0_cam_imu,
            self.dist,
            self.height,
            self.n_sub,
            NUMPY_OPS,
        )
        return np.stack([rx, ry], axis=1)
