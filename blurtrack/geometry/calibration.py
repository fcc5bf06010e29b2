"""The camera-IMU calibration: everything the blur model needs besides the gyro samples.

Conventions (docs/conventions.md, "Calibration file"): ``R_cam_imu`` maps IMU-frame vectors into
the camera frame; ``t_cam_imu_m`` is carried through (the pure-rotation blur model ignores it);
``timeshift_cam_imu_s`` follows Kalibr's sign, ``t_imu = t_cam + shift``; ``gyro_scale_matrix``
is the ``M`` of ``ω_meas = M R_cam_imuᵀ ω_cam + bias`` (IMU frame). Reading and writing the
Kalibr/OpenVINS YAML files is :mod:`blurtrack.io.calibration`'s job; this module knows no format.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from blurtrack.errors import ConfigError
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import is_rotation


@dataclass(frozen=True)
class Calibration:
    """Everything the blur model needs besides the gyro samples."""

    camera: Camera
    R_cam_imu: np.ndarray = field(default_factory=lambda: np.eye(3))
    timeshift_cam_imu_s: float = 0.0
    gyro_bias_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t_cam_imu_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma: dict[str, Any] = field(default_factory=dict)
    gyro_scale_matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    #: Set on a PARTIAL calibration (the extra key ``partial``): what was decided from the
    #: data and why the rest was not fitted, e.g. ``{"decided": "camera-IMU axes and a
    #: coarse time offset", "reason": "..."}``; commands that use it say so. ``None``: a fit.
    partial: dict[str, str] | None = None

    def __post_init__(self) -> None:
        if self.partial is not None:
            if not isinstance(self.partial, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in self.partial.items()
            ):
                raise ConfigError("partial must be a mapping of text to text")
            object.__setattr__(self, "partial", dict(self.partial))
        R = np.array(self.R_cam_imu, dtype=float)
        if not is_rotation(R, tol=1e-5):
            raise ConfigError("T_cam_imu's rotation block is not a rotation matrix")
        # Re-orthonormalise what passed the tolerance so downstream maths is exact.
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        R.setflags(write=False)
        bias = np.array(self.gyro_bias_radps, dtype=float).reshape(-1)
        t = np.array(self.t_cam_imu_m, dtype=float).reshape(-1)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise ConfigError(f"gyro_bias_radps must be 3 finite numbers, got {bias.tolist()}")
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ConfigError("T_cam_imu's translation must be 3 finite numbers")
        shift = float(self.timeshift_cam_imu_s)
        if not math.isfinite(shift) or abs(shift) > 10.0:
            raise ConfigError(f"timeshift_cam_imu must be finite and under 10 s, got {shift}")
        M = np.array(self.gyro_scale_matrix, dtype=float)
        if M.shape != (3, 3) or not np.all(np.isfinite(M)) or not 0.5 < np.linalg.det(M) < 1.5:
            raise ConfigError("gyro_scale_matrix must be a finite 3x3 matrix near the identity")
        M.setflags(write=False)
        object.__setattr__(self, "gyro_scale_matrix", M)
        bias.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R_cam_imu", R)
        object.__setattr__(self, "gyro_bias_radps", bias)
        object.__setattr__(self, "t_cam_imu_m", t)
        object.__setattr__(self, "timeshift_cam_imu_s", shift)
        object.__setattr__(self, "sigma", dict(self.sigma))

    @property
    def partial_label(self) -> str | None:
        """One line saying what a partial calibration holds (None for a fitted one)."""
        if self.partial is None:
            return None
        return (
            f"PARTIAL calibration: {self.partial.get('decided', 'not fitted')} only "
            f"({self.partial.get('reason', 'the fit was refused')})"
        )

    @property
    def T_cam_imu(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R_cam_imu
        T[:3, 3] = self.t_cam_imu_m
        return T

    def with_(self, **changes: Any) -> Calibration:
        """A copy with some fields replaced (``camera`` fields may be given by name too)."""
        cam_keys = {
            "intrinsics",
            "resolution",
            "distortion_model",
            "distortion_coeffs",
            "readout_s",
        }
        cam_changes = {k: changes.pop(k) for k in list(changes) if k in cam_keys}
        cam = replace(self.camera, **cam_changes) if cam_changes else self.camera
        return replace(self, camera=cam, **changes)
