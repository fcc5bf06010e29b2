"""Cameras: file replay through OpenCV, the virtual camera's schedule and buffer drops."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rigs.camera import OpenCvCamera, open_camera
from rigs.clock import ManualClock
from rigs.errors import DeviceError, DeviceUrlError
from rigs.fake_camera import VirtualCamera, VirtualCameraConfig, dot_grid_renderer


def _write_video(path: Path, n: int, fps: float) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    assert writer.isOpened()
    for i in range(n):
        img = np.zeros((48, 64, 3), np.uint8)
        img[:, : 4 * i + 4] = 255  # a bar that grows: frames are distinguishable
        writer.write(img)
    writer.release()


def test_file_replay_timestamps_follow_the_file(tmp_path: Path) -> None:
    path = tmp_path / "v.avi"
    _write_video(path, 12, 25.0)
    clock = ManualClock(start_ns=10**12)
    cam = open_camera(f"file://{path}?exposure_ms=4", clock=clock)
    assert isinstance(cam, OpenCvCamera)
    frames = []
    while (f := cam.read()) is not None:
        frames.append(f)
    cam.close()
    assert len(frames) == 12 and cam.frames_dropped == 0
    stamps = np.array([f.timestamp_ns for f in frames])
    np.testing.assert_allclose(np.diff(stamps), 40e6, atol=1e3)
    assert stamps[0] >= 10**12 and all(f.exposure_ns == 4_000_000 for f in frames)
    widths = [int((f.image[24, :, 0] > 128).sum()) for f in frames]
    assert widths == sorted(widths) and widths[0] < widths[-1]


def test_virtual_camera_schedule_and_exposure() -> None:
    clock = ManualClock(start_ns=5_000)
    cam = VirtualCamera(
        dot_grid_renderer(80, 60),
        VirtualCameraConfig(fps=50.0, exposure_s=0.004, n_frames=3, realtime=False),
        clock,
    )
    frames = [cam.read() for _ in range(4)]
    assert frames[3] is None
    assert [f.timestamp_ns for f in frames[:3]] == [5_000, 20_005_000, 40_005_000]
    assert all(f.exposure_ns == 4_000_000 and f.stamp_source == "driver" for f in frames[:3])
    assert frames[0].image.shape == (60, 80) and frames[0].image.dtype == np.uint8
    assert not np.array_equal(frames[0].image, frames[1].image)  # the grid moves


def test_virtual_camera_slow_reader_loses_frames_beyond_the_buffer() -> None:
    clock = ManualClock(start_ns=0)
    cam = VirtualCamera(
        lambda t: np.full((4, 4), int(t * 100) % 256, np.uint8),
        VirtualCameraConfig(fps=100.0, exposure_s=0.001, buffer_frames=4),
        clock,
    )
    clock.advance_s(0.0015)
    assert cam.read().index == 0
    clock.advance_s(0.2)  # 20 frame periods late; the ring buffer holds 4
    f = cam.read()
    assert cam.frames_dropped == f.index - 1 == 20 - 4


@pytest.mark.parametrize(
    ("url", "error", "match"),
    [
        ("sim://camera?fps=0", DeviceUrlError, "outside"),
        ("sim://camera?fps=100&exposure_ms=20", DeviceUrlError, "exposure"),
        ("sim://cam", DeviceUrlError, "sim://camera"),
        ("v4l2://abc", DeviceUrlError, "integer"),
        ("file:///nonexistent/blurtrack.mp4", DeviceError, "cannot open"),
        ("http://x", DeviceUrlError, "unknown camera scheme"),
        ("sim://camera?zoom=2", DeviceUrlError, "unknown option"),
    ],
)
def test_bad_camera_urls(url: str, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        open_camera(url)


def test_shared_origin_puts_imu_and_camera_on_one_timeline() -> None:
    from rigs.fake_imu import VirtualImu, VirtualImuConfig

    clock = ManualClock(start_ns=7_000_000_000)
    origin = clock.now_ns()
    seen: list[float] = []
    cam = VirtualCamera(
        lambda t: (seen.append(t), np.zeros((2, 2), np.uint8))[1],
        VirtualCameraConfig(fps=20.0, exposure_s=0.01, realtime=False, origin_ns=origin),
        clock,
    )
    clock.advance_s(3.0)  # the camera was created long before it is read
    frames = [cam.read() for _ in range(3)]
    assert seen == [0.0, 0.05, 0.1]
    assert [f.timestamp_ns - origin for f in frames] == [0, 50_000_000, 100_000_000]
    # a real-time board on the same origin has, 3 s later, sampled exactly 0 .. 3 s
    import time

    import serial

    from rigs.imu import ImuDriver

    imu = VirtualImu(
        lambda t: np.stack([t, t, t], axis=1),
        VirtualImuConfig(rate_hz=200.0, realtime=True, origin_ns=origin),
        clock,
    )
    drv = ImuDriver(serial.Serial(imu.open_pty(), timeout=0.05), "sim://imu", far_end=imu)
    imu.start()
    try:
        got = []
        end = time.monotonic() + 60.0
        while sum(len(b) for b in got) < 601 and time.monotonic() < end:
            got.append(drv.read())
        for _ in range(5):  # the clock stands still: nothing more may come
            got.append(drv.read())
        t_us = np.concatenate([b.t_dev_us for b in got])
        np.testing.assert_array_equal(t_us, np.arange(601) * 5000)
        gyro = np.concatenate([b.gyro_radps for b in got])
        np.testing.assert_allclose(gyro[:, 0], np.arange(601) / 200.0, atol=1e-6)
    finally:
        drv.close()
