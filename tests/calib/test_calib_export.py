"""Exporters: OpenVINS file reads back through cv::FileStorage, camera_info through YAML."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import so3_exp
from blurtrack.io.calibration import Calibration
from calib.export import write_camera_info, write_openvins


def _calib() -> Calibration:
    cam = Camera(
        (1280, 720),
        (1001.5, 999.0, 640.2, 361.7),
        "radtan",
        (-0.1, 0.02, 1e-3, -2e-3),
        readout_s=0.021,
    )
    return Calibration(
        cam,
        R_cam_imu=so3_exp(np.array([0.1, -0.2, 0.3])),
        t_cam_imu_m=np.array([0.01, 0.02, -0.03]),
        timeshift_cam_imu_s=-0.0042,
    )


def test_openvins_round_trip_through_opencv(tmp_path: Path) -> None:
    c = _calib()
    p = tmp_path / "kalibr_imucam_chain.yaml"
    write_openvins(c, p)
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    node = fs.getNode("cam0")
    T = np.array(
        [[node.getNode("T_imu_cam").at(i).at(j).real() for j in range(4)] for i in range(4)]
    )
    np.testing.assert_allclose(T @ c.T_cam_imu, np.eye(4), atol=1e-12)
    intr = [node.getNode("intrinsics").at(i).real() for i in range(4)]
    assert intr == list(c.camera.intrinsics)
    assert node.getNode("timeshift_cam_imu").real() == c.timeshift_cam_imu_s
    assert node.getNode("distortion_model").string() == "radtan"
    fs.release()


def test_camera_info(tmp_path: Path) -> None:
    c = _calib()
    p = tmp_path / "camera_info.yaml"
    write_camera_info(c, p)
    d = yaml.safe_load(p.read_text())
    K = np.array(d["camera_matrix"]["data"]).reshape(3, 3)
    np.testing.assert_allclose(K, c.camera.K)
    assert d["distortion_coefficients"]["data"][:4] == list(c.camera.distortion_coeffs)
    assert (d["image_width"], d["image_height"]) == (1280, 720)
    P = np.array(d["projection_matrix"]["data"]).reshape(3, 4)
    np.testing.assert_allclose(P[:, :3], c.camera.K)
