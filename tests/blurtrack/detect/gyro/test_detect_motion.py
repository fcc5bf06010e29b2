"""The gyro's motion against the images' (:mod:`blurtrack.detect.gyro.motion`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blurtrack.detect.frame import detect_frame
from blurtrack.detect.gyro.motion import MOTION_RATIO, GyroMotion, gyro_motion
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session
from blurtrack.testing.streak_frames import line_grid, quantise, render_streaks

#: The rendered streaks' start-to-end vector (px).
VECTOR = (14.0, 6.0)


@pytest.fixture(scope="module")
def calib(tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("motion") / "s"
    write_synthetic_session(folder, n_frames=2, seed=4)
    return load_session(folder).initial_calibration().with_(timeshift_cam_imu_s=0.0)


@pytest.fixture(scope="module")
def frame():
    curves = line_grid(12, 6, (30.0, 40.0), (50.0, 60.0), VECTOR)
    return detect_frame(quantise(render_streaks((200, 340), curves, 2.0, 1.5, 0.03, 0.004, 0)))


def _constant(omega_radps: tuple[float, float, float]) -> GyroTrace:
    t = np.arange(-1.0, 2.0, 0.005)
    return GyroTrace(t, np.tile(np.asarray(omega_radps, float), (t.size, 1)))


def test_a_constant_rate_turns_the_camera_by_f_omega_t(calib, frame) -> None:
    f = float(np.mean(calib.camera.intrinsics[:2]))
    exposure = 0.02
    length = float(np.hypot(*VECTOR))
    w = length / (f * exposure)  # the rate that moves a point by the streaks' length
    timings = [FrameTiming(0.5, exposure)]
    m = gyro_motion([frame], timings, calib, _constant((0.6 * w, 0.0, 0.8 * w)))
    assert m is not None and m.frames == 1
    assert m.gyro_px == pytest.approx(length, rel=1e-9)  # |omega| f T, any axis
    assert m.image_px == pytest.approx(length, abs=0.5)
    assert m.agrees and m.as_dict()["status"] == "agrees"


@pytest.mark.parametrize(
    ("scale", "agrees"),
    [(0.0, False), (0.19, False), (0.21, True), (4.9, True), (5.1, False), (57.3, False)],
)
def test_the_motion_agrees_within_the_ratio_either_way(calib, frame, scale, agrees) -> None:
    f = float(np.mean(calib.camera.intrinsics[:2]))
    w = float(np.hypot(*VECTOR)) / (f * 0.02)
    m = gyro_motion([frame], [FrameTiming(0.5, 0.02)], calib, _constant((0.0, scale * w, 0.0)))
    assert m is not None
    # The image's median length is the rendered one within half a pixel; the ratio's bounds
    # are 1/5 and 5 of it.
    assert m.agrees is agrees
    if not agrees:
        words = "dead" if scale < 1 else "degrees/s"
        assert words in m.message() and m.as_dict()["status"] == "contradicted"


def test_the_ratio_bounds_are_inclusive() -> None:
    assert GyroMotion(10.0 / MOTION_RATIO, 10.0, 1).agrees
    assert GyroMotion(10.0 * MOTION_RATIO, 10.0, 1).agrees
    assert not GyroMotion(10.0 * MOTION_RATIO * 1.001, 10.0, 1).agrees


def test_nothing_to_compare_without_long_streaks_or_coverage(calib, frame) -> None:
    empty = detect_frame(np.full((100, 100), 8, np.uint8))
    gyro = _constant((0.0, 1.0, 0.0))
    assert gyro_motion([empty], [FrameTiming(0.5, 0.02)], calib, gyro) is None
    # A frame the gyro does not cover at every shift tried (+-50 ms): none.
    assert gyro_motion([frame], [FrameTiming(1.98, 0.02)], calib, gyro) is None


def test_the_session_rig_agrees(tmp_path: Path) -> None:
    write_synthetic_session(tmp_path / "s", n_frames=3, seed=5)
    s = load_session(tmp_path / "s")
    frames = [detect_frame(s.read_image(k)) for k in range(3)]
    timings = [
        FrameTiming(float(t), float(e)) for t, e in zip(s.frame_times_s, s.exposures_s, strict=True)
    ]
    m = gyro_motion(frames, timings, s.initial_calibration(), s.gyro())
    assert m is not None and m.agrees
    assert 1.0 / 2.0 < m.gyro_px / m.image_px < 2.0
