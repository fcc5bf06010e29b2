"""Calibration files: Kalibr ``camchain-imucam.yaml`` keys plus BlurTrack's extra keys.

Reads and writes :class:`blurtrack.geometry.calibration.Calibration` values. See
docs/conventions.md ("Calibration file"). ``T_cam_imu`` maps IMU-frame vectors into the camera
frame; only its rotation matters to the pure-rotation blur model, its translation is carried
through.
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
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import BlurTrackError, ConfigError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.cvyaml import read_cv_yaml
from blurtrack.io.yamlio import write_yaml

#: The image topic written into calibration files (the one ``blurtrack export rosbag`` uses).
ROSTOPIC = "/cam0/image_raw"


def calibration_to_dict(calib: Calibration) -> dict[str, Any]:
    """The Kalibr layout ``{"cam0": {...}}`` with BlurTrack's extra keys (plain Python values)."""
    cam = calib.camera
    radtan = cam.distortion_model == "radtan" and cam.distortion_coeffs
    entry: dict[str, Any] = {
        "camera_model": "pinhole",
        "intrinsics": [float(v) for v in cam.intrinsics],
        "distortion_model": "radtan",
        "distortion_coeffs": (
            [float(v) for v in cam.distortion_coeffs] if radtan else [0.0, 0.0, 0.0, 0.0]
        ),
        "resolution": [int(v) for v in cam.resolution],
        "T_cam_imu": [[float(v) for v in row] for row in calib.T_cam_imu],
        "timeshift_cam_imu": float(calib.timeshift_cam_imu_s),
        "rostopic": ROSTOPIC,
        "cam_overlaps": [],
        "line_delay": float(cam.readout_s) / int(cam.height),
        "readout_s": float(cam.readout_s),
        "gyro_bias_radps": [float(v) for v in calib.gyro_bias_radps],
    }
    if not np.array_equal(calib.gyro_scale_matrix, np.eye(3)):
        entry["gyro_scale_matrix"] = calib.gyro_scale_matrix.tolist()
    if calib.sigma:
        entry["sigma"] = _plain(calib.sigma)
    if calib.partial is not None:
        entry["partial"] = dict(calib.partial)
    return {"cam0": entry}


def calibration_from_dict(data: Any, source: str = "calibration") -> Calibration:
    """A :class:`Calibration` from the Kalibr layout; ``source`` names it in errors."""
    if not isinstance(data, dict) or not isinstance(data.get("cam0"), dict):
        raise ConfigError(f"{source}: expected a mapping with a 'cam0' entry (Kalibr layout)")
    c = data["cam0"]
    try:
        model = c.get("camera_model", "pinhole")
        if model != "pinhole":
            raise ConfigError(f"{source}: camera_model {model!r} is not supported (only pinhole)")
        camera = Camera(
            resolution=tuple(c["resolution"]),
            intrinsics=tuple(c["intrinsics"]),
            **_distortion(c),
            readout_s=_readout_s(c),
        )
        T = _T_cam_imu(c, source)
        return Calibration(
            camera=camera,
            R_cam_imu=T[:3, :3],
            t_cam_imu_m=T[:3, 3],
            timeshift_cam_imu_s=float(c["timeshift_cam_imu"]),  # required: no silent 0
            gyro_bias_radps=np.array(c.get("gyro_bias_radps", [0.0, 0.0, 0.0]), float),
            sigma=dict(c.get("sigma") or {}),
            gyro_scale_matrix=np.array(c.get("gyro_scale_matrix", np.eye(3).tolist()), dtype=float),
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


def read_calibration(path: str | Path) -> Calibration:
    """This project's file, a Kalibr camchain, or an OpenVINS ``%YAML:1.0`` chain file."""
    return calibration_from_dict(read_cv_yaml(path, "calibration file"), source=str(path))


def write_calibration(calib: Calibration, path: str | Path) -> None:
    """Write ``calib`` as this project's (Kalibr-readable) YAML file."""
    write_yaml(path, calibration_to_dict(calib))


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
