"""blurtrack/io/turn.py: a session's frames and camera turned by 180 degrees."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blurtrack.geometry.camera import Camera
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, load_session
from blurtrack.io.turn import turn_session_files


def _session(folder: Path) -> list[np.ndarray]:
    rng = np.random.default_rng(4)
    frames = [rng.integers(0, 65535, (6, 8, 3), dtype=np.uint16) for _ in range(3)]
    T = np.eye(4)
    T[:3, :3] = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]
    T[:3, 3] = [0.01, -0.02, 0.03]
    camera = Camera(
        resolution=(8, 6),
        intrinsics=(9.0, 9.5, 3.0, 2.0),
        distortion_model="radtan",
        distortion_coeffs=(0.1, -0.01, 0.002, 0.003),
        readout_s=0.01,
    )
    meta = SessionMeta(camera=camera, imu=ImuConfig(rate_hz=100.0, T_cam_imu=T))
    with SessionWriter(folder, meta) as w:
        w.add_imu(np.arange(0, 500_000_000, 10_000_000), np.full((50, 3), 0.1))
        for k, img in enumerate(frames):
            w.add_frame(100_000_000 * (k + 1), img, 5_000_000)
    return frames


def test_sixteen_bit_colour_frames_and_the_camera_turn_and_turn_back(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    frames = _session(folder)
    before = load_session(folder)
    assert turn_session_files(folder) == 3
    s = load_session(folder)
    for i, img in enumerate(frames):
        got = s.read_image(i)
        assert got.dtype == np.uint16 and got.shape == (6, 8, 3)
        np.testing.assert_array_equal(got, img[::-1, ::-1])
    assert s.meta.camera.intrinsics == (9.0, 9.5, 4.0, 3.0)
    assert s.meta.camera.distortion_coeffs == (0.1, -0.01, -0.002, -0.003)
    assert s.meta.camera.readout_s == 0.01
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(s.meta.imu.T_cam_imu, flip @ before.meta.imu.T_cam_imu)
    np.testing.assert_array_equal(s.omega_radps, before.omega_radps)
    np.testing.assert_array_equal(s.frame_times_s, before.frame_times_s)
    turn_session_files(folder)  # turned twice: as written
    again = load_session(folder)
    for i, img in enumerate(frames):
        np.testing.assert_array_equal(again.read_image(i), img)
    assert again.meta.camera == before.meta.camera
    np.testing.assert_allclose(again.meta.imu.T_cam_imu, before.meta.imu.T_cam_imu)
