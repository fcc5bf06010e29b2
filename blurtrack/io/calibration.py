"""Calibration files: Kalibr ``camchain-imucam.yaml`` keys plus BlurTrack's extra keys.

See docs/conventions.md ("Calibration file"). ``T_cam_imu`` maps IMU-frame vectors into the camera
frame;
only its rotation matters to the pure-rotation blur model, its translation is carried through.
``timeshift_cam_imu`` follows Kalibr's sign: ``t_imu = t_cam + shift``. The optional extra key
``gyro_scale_matrix`` is the ``M`` of ``ω_meas = M R_cam_imuᵀ ω_cam + bias`` (gyro scale and
cross-axis error, IMU frame); it is written only when it differs from the identity.

Written for Kalibr's readers as well: ``rostopic``, ``cam_overlaps``, ``distortion_model:
radtan`` with zeros for an undistorted camera (Kalibr's ``none`` branch is broken), and
``line_delay`` (s per row, Kalibr's rolling-shutter key) beside ``readout_s``. Read back: this
file, Kalibr's ``camchain(-imucam).yaml`` (cam0) and OpenVINS/OpenCV chain files (``%YAML:1.0``
header, ``T_imu_cam`` = the inverse of ``T_cam_imu``). An all-zero radtan reads as ``none``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import BlurTrackError, ConfigError
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import is_rotation
from blurtrack.io.cvyaml import read_cv_yaml
from blurtrack.io.yamlio import write_yaml

#: The image topic written into calibration files (the one ``blurtrack export rosbag`` uses).
ROSTOPIC = "/cam0/image_raw"


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

    # ----------------------------------------------------------------- YAML
    def to_dict(self) -> dict[str, Any]:
        cam = self.camera
        radtan = cam.distortion_model == "radtan" and cam.distortion_coeffs
        entry: dict[str, Any] = {
            "camera_model": "pinhole",
            "intrinsics": [float(v) for v in cam.intrinsics],
            "distortion_model": "radtan",
            "distortion_coeffs": (
                [float(v) for v in cam.distortion_coeffs] if radtan else [0.0, 0.0, 0.0, 0.0]
            ),
            "resolution": [int(v) for v in cam.resolution],
            "T_cam_imu": [[float(v) for v in row] for row in self.T_cam_imu],
            "timeshift_cam_imu": float(self.timeshift_cam_imu_s),
            "rostopic": ROSTOPIC,
            "cam_overlaps": [],
            "line_delay": float(cam.readout_s) / int(cam.height),
            "readout_s": float(cam.readout_s),
            "gyro_bias_radps": [float(v) for v in self.gyro_bias_radps],
        }
        if not np.array_equal(self.gyro_scale_matrix, np.eye(3)):
            entry["gyro_scale_matrix"] = self.gyro_scale_matrix.tolist()
        if self.sigma:
            entry["sigma"] = _plain(self.sigma)
        if self.partial is not None:
            entry["partial"] = dict(self.partial)
        return {"cam0": entry}

    @classmethod
    def from_dict(cls, data: Any, source: str = "calibration") -> Calibration:
        if not isinstance(data, dict) or not isinstance(data.get("cam0"), dict):
            raise ConfigError(f"{source}: expected a mapping with a 'cam0' entry (Kalibr layout)")
        c = data["cam0"]
        try:
            model = c.get("camera_model", "pinhole")
            if model != "pinhole":
                raise ConfigError(
                    f"{source}: camera_model {model!r} is not supported (only pinhole)"
                )
            camera = Camera(
                resolution=tuple(c["resolution"]),
                intrinsics=tuple(c["intrinsics"]),
                **_distortion(c),
                readout_s=_readout_s(c),
            )
            T = _T_cam_imu(c, source)
            return cls(
                camera=camera,
                R_cam_imu=T[:3, :3],
                t_cam_imu_m=T[:3, 3],
                timeshift_cam_imu_s=float(c["timeshift_cam_imu"]),  # required: no silent 0
                gyro_bias_radps=np.array(c.get("gyro_bias_radps", [0.0, 0.0, 0.0]), float),
                sigma=dict(c.get("sigma") or {}),
                gyro_scale_matrix=np.array(
                    c.get("gyro_scale_matrix", np.eye(3).tolist()), dtype=float
                ),
                partial=c.get("partial"),
            )
        except ConfigError:
            raise
        except BlurTrackError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        except KeyError as exc:
            raise ConfigError(f"{source}: cam0 lacks the key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: malformed value ({exc})") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> Calibration:
        """This project's file, a Kalibr camchain, or an OpenVINS ``%YAML:1.0`` chain file."""
        return cls.from_dict(read_cv_yaml(path, "calibration file"), source=str(path))

    def to_yaml(self, path: str | Path) -> None:
        write_yaml(path, self.to_dict())


def _distortion(c: dict[str, Any]) -> dict[str, Any]:
    """``distortion_model``/``coeffs``; an all-zero radtan (Kalibr's undistorted) is ``none``."""
    model = c.get("distortion_model", "none")
    coeffs = tuple(float(v) for v in c.get("distortion_coeffs") or ())
    if model == "radtan" and not any(coeffs):
        model, coeffs = "none", ()
    return {"distortion_model": model, "distortion_coeffs": coeffs}


def _readout_s(c: dict[str, Any]) -> float:
    """``readout_s``, else Kalibr's ``line_delay`` (s per row) times the image height."""
    if "readout_s" in c or "line_delay" not in c:
        return float(c.get("readout_s", 0.0))
    line_delay = float(c["line_delay"])
    if not (math.isfinite(line_delay) and 0.0 <= line_delay < 1e-3):
        raise ConfigError(f"line_delay must be in [0, 1 ms) per row, got {line_delay}")
    return line_delay * int(c["resolution"][1])


def _T_cam_imu(c: dict[str, Any], source: str) -> np.ndarray:
    """Kalibr's ``T_cam_imu``, or the inverse of OpenVINS's ``T_imu_cam``."""
    inverse = "T_cam_imu" not in c and "T_imu_cam" in c
    if not inverse and "T_cam_imu" not in c:
        raise ConfigError(f"{source}: lacks the key 'T_cam_imu' (required: no silent identity)")
    try:
        T = np.array(c["T_imu_cam"] if inverse else c["T_cam_imu"], dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: the camera-IMU transform is not a numeric matrix") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        key = "T_imu_cam" if inverse else "T_cam_imu"
        raise ConfigError(f"{source}: {key} must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise ConfigError(f"{source}: the last row of the transform must be [0, 0, 0, 1]")
    if inverse:
        T = np.eye(4)
        R, p = np.array(c["T_imu_cam"], float)[:3, :3], np.array(c["T_imu_cam"], float)[:3, 3]
        T[:3, :3], T[:3, 3] = R.T, -R.T @ p
    return T


def _plain(obj: Any) -> Any:
    """numpy scalars and arrays to plain Python for YAML."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
