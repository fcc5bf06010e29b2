"""Exporters of a calibration for other tools: OpenVINS and ROS ``camera_info``.

- OpenVINS reads ``kalibr_imucam_chain.yaml`` through ``cv::FileStorage``: the file starts with
  the ``%YAML:1.0`` directive and holds ``T_imu_cam`` (camera to IMU, the inverse of Kalibr's
  ``T_cam_imu``) as rows of a flow sequence; ``timeshift_cam_imu`` keeps Kalibr's sign.
- Kalibr's own files are the calibration file itself (``Calibration.to_yaml``: camchain keys
  incl. ``rostopic``, ``cam_overlaps``, ``line_delay``) and :func:`write_kalibr_imu`
  (``imu.yaml``, from ``blurtrack.io.kalibr_imu``).
- ROS ``camera_info`` YAML (camera_calibration_parsers): ``camera_matrix``,
  ``distortion_coefficients`` (``plumb_bob`` = OpenCV k1 k2 p1 p2 k3), ``rectification_matrix``
  and ``projection_matrix``.

PyYAML cannot write the ``%YAML:1.0`` directive form that OpenCV requires, so the OpenVINS file
is formatted by hand (a handful of fixed keys); the result is checked by reading it back with
``cv2.FileStorage`` in the tests.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from blurtrack.geometry.calibration import Calibration
from blurtrack.io.calibration import ROSTOPIC
from blurtrack.io.kalibr_imu import write_kalibr_imu
from blurtrack.io.yamlio import write_text_atomic

__all__ = ["camera_info_dict", "openvins_text", "write_camera_info", "write_kalibr_imu",
           "write_openvins"]  # fmt: skip


def _num(v: float) -> str:
    return repr(float(v))


def _seq(values: Any) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def openvins_text(calib: Calibration) -> str:
    """OpenVINS ``kalibr_imucam_chain.yaml`` content (cv::FileStorage YAML)."""
    cam = calib.camera
    T_imu_cam = np.linalg.inv(calib.T_cam_imu)
    dist = list(cam.distortion_coeffs) or [0.0, 0.0, 0.0, 0.0]
    lines = [
        "%YAML:1.0",
        "---",
        "cam0:",
        "  T_imu_cam:  # camera to IMU: R_CtoI, p_CinI",
        *[f"    - {_seq(row)}" for row in T_imu_cam],
        "  cam_overlaps: []",
        "  camera_model: pinhole",
        f"  distortion_coeffs: {_seq(dist)}",
        "  distortion_model: radtan",
        f"  intrinsics: {_seq(cam.intrinsics)}",
        f"  resolution: [{cam.width}, {cam.height}]",
        f"  timeshift_cam_imu: {_num(calib.timeshift_cam_imu_s)}",
        f"  readout_s: {_num(cam.readout_s)}",
        f"  rostopic: {ROSTOPIC}",
    ]
    return "\n".join(lines) + "\n"


def camera_info_dict(calib: Calibration, camera_name: str = "cam0") -> dict[str, Any]:
    """ROS ``camera_info`` YAML mapping (camera_calibration_parsers layout)."""
    cam = calib.camera
    fx, fy, cx, cy = cam.intrinsics
    d = [*cam.distortion_coeffs, 0.0] if cam.distortion_coeffs else [0.0] * 5
    return {
        "image_width": cam.width,
        "image_height": cam.height,
        "camera_name": camera_name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [float(v) for v in d]},
        "rectification_matrix": {
            "rows": 3,
            "cols": 3,
            "data": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        },
        "projection_matrix": {
            "rows": 3,
            "cols": 4,
            "data": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        },
    }


def write_openvins(calib: Calibration, path: str | Path) -> None:
    write_text_atomic(path, openvins_text(calib))


def write_camera_info(calib: Calibration, path: str | Path, camera_name: str = "cam0") -> None:
    write_text_atomic(
        path,
        yaml.safe_dump(
            camera_info_dict(calib, camera_name), sort_keys=False, default_flow_style=None
        ),
    )
