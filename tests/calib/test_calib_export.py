"""Exporters: OpenVINS file reads back through cv::FileStorage, camera_info through YAML."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from blurtrack.errors import ConfigError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import so3_exp
from blurtrack.io.calibration import read_calibration, write_calibration
from calib.export import write_camera_info, write_kalibr_imu, write_openvins


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


def test_calibration_file_has_kalibr_keys_and_reads_back(tmp_path: Path) -> None:
    c = _calib()
    undistorted = c.with_(distortion_model="none", distortion_coeffs=())
    write_calibration(undistorted, tmp_path / "c.yaml")
    d = yaml.safe_load((tmp_path / "c.yaml").read_text())["cam0"]
    assert d["rostopic"] == "/cam0/image_raw" and d["cam_overlaps"] == []
    assert d["distortion_model"] == "radtan" and d["distortion_coeffs"] == [0.0] * 4
    assert d["line_delay"] == pytest.approx(0.021 / 720)  # s per row
    back = read_calibration(tmp_path / "c.yaml")
    assert back.camera == undistorted.camera  # all-zero radtan reads as none


def test_kalibr_camchain_reads_back(tmp_path: Path) -> None:
    # The layout kalibr_calibrate_imu_camera writes (camchain-imucam.yaml), two cameras.
    text = """cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  line_delay: 2.0e-05
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 0.0031
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, 0.11]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""
    (tmp_path / "camchain-imucam.yaml").write_text(text)
    c = read_calibration(tmp_path / "camchain-imucam.yaml")
    assert c.camera.intrinsics == (458.654, 457.296, 367.215, 248.375)
    assert c.camera.distortion_model == "radtan"
    assert c.camera.readout_s == pytest.approx(2e-5 * 480)
    assert c.timeshift_cam_imu_s == 0.0031
    assert c.R_cam_imu[0, 1] == pytest.approx(-0.999880929698, abs=1e-6)
    (tmp_path / "fisheye.yaml").write_text(text.replace("radtan", "equidistant"))
    with pytest.raises(ConfigError):
        read_calibration(tmp_path / "fisheye.yaml")


def test_own_openvins_file_reads_back(tmp_path: Path) -> None:
    c = _calib()
    p = tmp_path / "calib.openvins.yaml"
    write_openvins(c, p)
    assert p.read_text().startswith("%YAML:1.0\n")
    back = read_calibration(p)
    np.testing.assert_allclose(back.T_cam_imu, c.T_cam_imu, atol=1e-12)
    assert back.camera == c.camera
    assert back.timeshift_cam_imu_s == c.timeshift_cam_imu_s
    (tmp_path / "evil.yaml").write_text("%YAML:1.0\n!!python/object/apply:os.system ['true']\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        read_calibration(tmp_path / "evil.yaml")


def test_kalibr_imu_file(tmp_path: Path) -> None:
    from blurtrack.io.kalibr_imu import DEFAULT_NOISE, NOISE_KEYS
    from blurtrack.io.session import load_session
    from blurtrack.testing.mini_session import write_synthetic_session

    write_synthetic_session(tmp_path / "s", n_frames=1, resolution=(32, 24))
    source = write_kalibr_imu(load_session(tmp_path / "s"), tmp_path / "imu.yaml")
    d = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    assert set(d) == {*NOISE_KEYS, "rostopic", "update_rate"}
    assert d["rostopic"] == "/imu0" and d["update_rate"] == 1000.0
    assert source.startswith("defaults") and d["gyroscope_noise_density"] == pytest.approx(
        DEFAULT_NOISE["gyroscope_noise_density"]
    )
