"""The simulated gyroscope: the true angular velocity as a MEMS gyro would report it.

``ω_meas(t_imu) = (I + S) R_cam_imuᵀ ω_cam(t_imu - timeshift) + bias + noise`` on the IMU clock
(``t_imu = t_cam + timeshift_cam_imu``, Kalibr's sign), where ``S`` is the scale and cross-axis
error and the noise is white Gaussian per sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigs.sim.errors import SimError


@dataclass(frozen=True)
class GyroModel:
    """True gyro parameters (IMU frame): misaligned mounting, bias, scale, noise, time offset."""

    R_cam_imu: np.ndarray
    timeshift_cam_imu_s: float
    bias_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: np.ndarray = field(default_factory=lambda: np.eye(3))  # I + S
    noise_radps: float = 0.0

    def __post_init__(self) -> None:
        R = np.asarray(self.R_cam_imu, dtype=float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9):
            raise SimError("gyro model: R_cam_imu must be a rotation matrix")
        object.__setattr__(self, "R_cam_imu", R)
        object.__setattr__(self, "bias_radps", np.asarray(self.bias_radps, float).reshape(3))
        object.__setattr__(self, "scale", np.asarray(self.scale, float).reshape(3, 3))
        if self.noise_radps < 0:
            raise SimError("gyro model: noise must be >= 0")

    def ideal(
        self, omega_cam_at: Callable[[np.ndarray], np.ndarray], t_imu_s: np.ndarray
    ) -> np.ndarray:
        """Noise-free measurement ``(M, 3)`` (rad/s, IMU frame) at IMU times ``(M,)``."""
        t = np.asarray(t_imu_s, dtype=float).reshape(-1)
        w_cam = omega_cam_at(t - self.timeshift_cam_imu_s)
        w_imu = w_cam @ self.R_cam_imu  # rows: (R_cam_imuᵀ ω_cam)ᵀ
        return w_imu @ self.scale.T + self.bias_radps

    def measure(
        self,
        omega_cam_at: Callable[[np.ndarray], np.ndarray],
        t_imu_s: np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Noisy measurement ``(M, 3)`` at IMU times ``(M,)``."""
        w = self.ideal(omega_cam_at, t_imu_s)
        if self.noise_radps > 0:
            w = w + rng.normal(0.0, self.noise_radps, w.shape)
        return w
