"""End to end on the simulated devices: recorder -> log -> session, kill -9, unplug, Ctrl-C.

Subprocess tests run the real ``blurtrack record`` CLI; every wait is bounded by a generous
deadline and every assertion is about data, never about how long something took.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main as cli_main
from blurtrack.io.session import load_session
from rigs.convert import ConvertOptions, log_to_session
from rigs.fake_camera import VirtualCamera, VirtualCameraConfig
from rigs.fake_imu import sine_motion
from rigs.imu import open_imu
from rigs.protocol import GYRO_SCALE_RADPS
from rigs.reclog import scan_log
from rigs.recorder import Recorder, RecorderConfig

REPO = Path(__file__).resolve().parents[2]
DEADLINE_S = 90.0


def expected_gyro(k: np.ndarray, rate_hz: float) -> np.ndarray:
    """What the default sim://imu board sends for sample numbers k (quantised sines)."""
    omega = sine_motion()(k / rate_hz)
    return np.rint(omega / GYRO_SCALE_RADPS).astype(np.int64) * GYRO_SCALE_RADPS


def test_recorder_keeps_every_intact_sample_at_one_percent_corruption(tmp_path: Path) -> None:
    n = 3000
    imu = open_imu(f"sim://imu?rate=1000&realtime=0&samples={n}&flip=0.01&seed=11")
    frames = [np.full((24, 32), 10 * i, np.uint8) for i in range(5)]
    cam = VirtualCamera(
        lambda t: frames[min(int(t * 10), 4)],
        VirtualCameraConfig(fps=10, exposure_s=0.005, n_frames=5, realtime=False),
    )
    # the camera ends long before the board: the recorder waits for the board's last sample
    rec = Recorder(
        tmp_path / "rec.mcap", imu, cam, {"imu_url": "sim"}, RecorderConfig(flush_interval_s=0.05)
    )
    dev = imu.far_end
    assert dev is not None
    result = rec.run()
    imu.close()
    assert result.error is None and result.stopped_by == "camera-ended"
    conv = log_to_session(tmp_path / "rec.mcap", tmp_path / "session")
    s = load_session(tmp_path / "session")
    got = scan_log(tmp_path / "rec.mcap").imu_index
    assert set(got.tolist()) == set(range(n)) - dev.damaged
    np.testing.assert_array_equal(s.omega_radps, dev.sent_gyro_radps[got])
    np.testing.assert_array_equal(s.omega_radps, expected_gyro(got, 1000.0))
    assert conv.imu_samples == got.size and len(s.frames) == 5
    st = result.imu_stats
    assert st["dropped"] == len({k for k in dev.damaged if got.min() < k < got.max()})
    assert st["crc_errors"] > 0 and s.meta.extra["recording"]["imu_stats"]["crc_errors"] > 0
    assert np.all(np.diff(s.imu_t_ns) > 0)


def _spawn(args: list[str]) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen(
        [sys.executable, "-m", "blurtrack", *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_flushed(proc: subprocess.Popen[str], imu_at_least: int) -> tuple[int, int]:
    """Read status lines until the flushed IMU count reaches ``imu_at_least``."""
    assert proc.stdout is not None
    timer = threading.Timer(DEADLINE_S, proc.kill)
    timer.start()
    try:
        for line in proc.stdout:
            if "flushed imu" in line:
                words = line.split()
                i = words.index("flushed")
                imu, frames = int(words[i + 2]), int(words[i + 4])
                if imu >= imu_at_least:
                    return imu, frames
    finally:
        timer.cancel()
    raise AssertionError(f"recorder ended early: {proc.stderr.read() if proc.stderr else ''}")


RECORD = [
    "record",
    "--imu",
    "sim://imu?rate=500",
    "--camera",
    "sim://camera?fps=10&width=64&height=48",
    "--flush-interval",
    "0.1",
]


def test_sigkill_then_recover_keeps_everything_flushed(tmp_path: Path) -> None:
    log = tmp_path / "killed.mcap"
    proc = _spawn([*RECORD, "--out", str(tmp_path / "never"), "--log", str(log)])
    try:
        flushed_imu, flushed_frames = _wait_for_flushed(proc, 600)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=DEADLINE_S)
    finally:
        proc.kill()
    assert proc.returncode == -signal.SIGKILL
    scan = scan_log(log)
    assert not scan.complete  # no footer: the recorder really died mid-recording
    rc = cli_main(["recover", str(log), "--session", str(tmp_path / "session")])
    assert rc == 0
    s = load_session(tmp_path / "session")
    recovered = scan_log(tmp_path / "killed.recovered.mcap")
    assert recovered.complete
    k = recovered.imu_index
    assert k.size >= flushed_imu and len(s.frames) >= flushed_frames
    np.testing.assert_array_equal(k, np.arange(k.size))  # a gap-free prefix
    np.testing.assert_array_equal(s.omega_radps, expected_gyro(k, 500.0))
    assert (tmp_path / "session" / "summary.json").is_file()


def test_unplug_mid_recording_gives_clear_error_and_usable_session(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "session"
    rc = cli_main(
        [
            "record",
            "--imu",
            "sim://imu?rate=1000&unplug=1.0",
            "--camera",
            "sim://camera?fps=20&width=64&height=48",
            "--out",
            str(out),
            "--duration",
            str(DEADLINE_S),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2
    assert "disconnected" in err and str(out) in err and err.count("\n") == 1
    s = load_session(out)
    k = scan_log(tmp_path / "session.mcap").imu_index
    assert 0 < k.size <= 1000
    np.testing.assert_array_equal(k, np.arange(k.size))
    np.testing.assert_array_equal(s.omega_radps, expected_gyro(k, 1000.0))
    assert len(s.frames) > 0


def test_ctrl_c_stops_cleanly(tmp_path: Path) -> None:
    out = tmp_path / "session"
    proc = _spawn([*RECORD, "--out", str(out)])
    try:
        _wait_for_flushed(proc, 100)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=DEADLINE_S)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    scan = scan_log(tmp_path / "session.mcap")
    assert scan.complete and scan.events[-1]["message"] == "recording stopped (stop)"
    s = load_session(out)
    assert s.omega_radps.shape[0] == scan.imu_index.size >= 100


def test_record_refuses_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    full = str(tmp_path / "full")
    cases = [
        (["record", "--out", str(tmp_path / "a")], "give --imu"),
        (["record", "--imu", "sim://imu", "--out", str(tmp_path / "c")], "needs camera frames"),
        (["record", "--camera", "sim://camera", "--out", str(tmp_path / "d")], "needs gyro"),
        (
            ["record", "--imu", "sim://imu", "--camera", "sim://camera", "--out", full],
            "not empty",
        ),
        (
            ["record", "--imu", "bogus://x", "--no-convert", "--out", str(tmp_path / "b")],
            "unknown IMU scheme",
        ),
        (["recover", str(tmp_path / "full" / "x")], "not a BlurTrack recorder log"),
        (["recover", str(tmp_path / "missing.mcap")], "cannot open log"),
    ]
    for argv, match in cases:
        assert cli_main(argv) == 2
        assert match in capsys.readouterr().err


def test_convert_requires_exposure_when_camera_reports_none(tmp_path: Path) -> None:
    from rigs.camera_types import CameraFrame
    from rigs.errors import RecorderLogError
    from rigs.reclog import RecLogWriter

    w = RecLogWriter(tmp_path / "l.mcap", {})
    import cv2

    png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1].tobytes()
    for i in range(3):
        frame = CameraFrame(i, np.zeros((8, 8), np.uint8), 1000 + i, -1, 5, "host")
        w.write_frame(frame, png, "png")
    w.write_imu(
        0, np.arange(4), np.arange(4) * 1000, np.arange(4) * 1_000_000 + 7, np.zeros((4, 3)), None
    )
    w.finish()
    with pytest.raises(RecorderLogError, match="exposure-ms"):
        log_to_session(tmp_path / "l.mcap", tmp_path / "s")
    res = log_to_session(tmp_path / "l.mcap", tmp_path / "s2", ConvertOptions(exposure_ns=2000))
    s = load_session(tmp_path / "s2")
    assert res.frames == 3 and s.frames.exposure_ns.tolist() == [2000] * 3
    assert s.accel_mps2 is None
    assert s.meta.imu.axes_known is False  # no --R-cam-imu, no rig guess: not passed as known


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: RecorderConfig(flush_interval_s=5.0), "crash loss bound"),
        (lambda: RecorderConfig(frame_encoding="jpeg"), "raw or png"),
        (lambda: VirtualCameraConfig(fps=30, exposure_s=0.1), "exposure_s"),
    ],
)
def test_configs_validate_themselves(make, match: str) -> None:
    from blurtrack.errors import BlurTrackError
    from rigs.errors import RigConfigError

    with pytest.raises(RigConfigError, match=match) as info:
        make()
    assert isinstance(info.value, BlurTrackError)


def test_recorder_needs_a_device(tmp_path: Path) -> None:
    from rigs.errors import RigError

    with pytest.raises(RigError, match="nothing to record"):
        Recorder(tmp_path / "x.mcap", None, None)


def test_imu_only_record_fails_fast(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A session needs frames: an IMU-only record is refused at once, not after --duration."""
    import time

    t0 = time.monotonic()
    rc = cli_main(
        ["record", "--imu", "sim://imu?rate=500", "--out", str(tmp_path / "s"), "--duration", "60"]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "needs camera frames" in err and len(err.splitlines()) == 1
    assert time.monotonic() - t0 < 30 and not (tmp_path / "s").exists()


def test_unplug_without_frames_keeps_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = cli_main(
        [
            "record",
            "--imu",
            "sim://imu?rate=500&unplug=0.2",
            "--no-convert",
            "--out",
            str(tmp_path / "session"),
            "--duration",
            str(DEADLINE_S),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "disconnected" in err
    k = scan_log(tmp_path / "session.mcap").imu_index
    np.testing.assert_array_equal(k, np.arange(k.size))
    assert 0 < k.size <= 100


def test_recover_writes_the_session_turned_and_keeps_the_log(tmp_path: Path) -> None:
    # A camera mounted upside down: --turn-180 turns the session's frames, never the log's.
    imu = open_imu("sim://imu?rate=1000&realtime=0&samples=1500&seed=3")
    frames = [
        np.arange(24 * 32, dtype=np.uint16).reshape(24, 32).astype(np.uint8) + i for i in range(4)
    ]
    cam = VirtualCamera(
        lambda t: frames[min(int(t * 10), 3)],
        VirtualCameraConfig(fps=10, exposure_s=0.005, n_frames=4, realtime=False),
    )
    log = tmp_path / "rec.mcap"
    result = Recorder(log, imu, cam, {"imu_url": "sim"}, RecorderConfig()).run()
    imu.close()
    assert result.error is None
    before = log.read_bytes()
    k = ["--intrinsics", "30,31,15,11"]
    assert cli_main(["recover", str(log), "--session", str(tmp_path / "up"), *k]) == 0
    argv = ["recover", str(log), "--out", str(tmp_path / "r2.mcap"), "--turn-180", *k]
    assert cli_main([*argv, "--session", str(tmp_path / "turned")]) == 0
    assert log.read_bytes() == before
    up, turned = load_session(tmp_path / "up"), load_session(tmp_path / "turned")
    assert len(turned.frames) == len(up.frames) == 4
    for i in range(4):
        np.testing.assert_array_equal(turned.read_image(i), up.read_image(i)[::-1, ::-1])
    assert turned.meta.camera.intrinsics == (30.0, 31.0, 16.0, 12.0)
    np.testing.assert_allclose(
        turned.meta.imu.T_cam_imu, np.diag([-1.0, -1.0, 1.0, 1.0]) @ up.meta.imu.T_cam_imu
    )
