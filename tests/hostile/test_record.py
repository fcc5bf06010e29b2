"""Hostile recordings: an IMU that sends nothing, stops by --duration, full disks on recover."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.io.session import load_session
from rigs.convert import log_to_session
from rigs.errors import RecorderLogError
from tests.hostile.conftest import debris, tree_hashes


def test_loop_imu_with_no_samples_fails(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rc = main(
        [
            "record",
            "--imu",
            "loop://",
            "--camera",
            "sim://camera?fps=30&width=64&height=48",
            "--out",
            str(tmp_path / "s"),
            "--duration",
            "0.4",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "delivered no samples" in err, err
    assert not (tmp_path / "s").exists() and debris(tmp_path) == []


def test_duration_stop_keeps_the_imu_past_the_last_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "s"
    rc = main(
        [
            "record",
            "--imu",
            "sim://imu?rate=1000",
            "--camera",
            "sim://camera?fps=30&width=64&height=48",
            "--out",
            str(out),
            "--duration",
            "0.5",
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0
    m = re.search(r"(\d+) samples received = (\d+) kept \+ (\d+) duplicates \+ (\d+) bad", text)
    assert m is not None, text
    received, kept, dup, bad = map(int, m.groups())
    assert received == kept + dup + bad and received > 0  # no time jumps on the virtual board
    s = load_session(out)
    assert s.imu_t_ns.size == kept == s.meta.extra["recording"]["imu_stats"]["kept"]
    last_end = s.frame_times_s[-1] + s.exposures_s[-1] + s.meta.imu.timeshift_cam_imu
    assert s.imu_times_s[-1] >= last_end + 0.2  # docs/recording.md: the IMU runs 0.3 s on


def test_recover_onto_a_full_disk(
    tmp_path: Path, full_dir: Path, capsys: pytest.CaptureFixture
) -> None:
    log = tmp_path / "rec.mcap"
    rc = main(
        [
            "record",
            "--imu",
            "sim://imu?rate=1000",
            "--camera",
            "sim://camera?fps=30&width=160&height=120",
            "--out",
            str(tmp_path / "s"),
            "--log",
            str(log),
            "--duration",
            "0.5",
            "--no-convert",
        ]
    )
    assert rc == 0
    capsys.readouterr()
    rc = main(
        ["recover", str(log), "--out", str(tmp_path / "r.mcap"), "--session", str(full_dir / "s")]
    )
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "no space left" in err, err
    assert not (full_dir / "s").exists(), "a half session was left behind"
    assert debris(tmp_path) == []


def test_record_onto_a_full_disk(
    tmp_path: Path, full_dir: Path, capsys: pytest.CaptureFixture
) -> None:
    """The log's disk fills while recording: one line, exit 2, no half session, no debris."""
    rc = main(
        [
            "record",
            "--imu",
            "sim://imu?rate=1000",
            "--camera",
            "sim://camera?fps=30&width=160&height=120",
            "--out",
            str(tmp_path / "s"),
            "--log",
            str(full_dir / "rec.mcap"),
            "--duration",
            "1",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "no space left" in err or "No space left" in err
    assert not (tmp_path / "s").exists() and debris(tmp_path) == []


def test_ctrl_c_keeps_the_imu_past_the_last_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """SIGINT (Ctrl-C) stops the camera first; the IMU covers the last exposure."""
    import os
    import signal
    import threading

    out = tmp_path / "s"
    timer = threading.Timer(1.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        rc = main(
            [
                "record",
                "--imu",
                "sim://imu?rate=1000",
                "--camera",
                "sim://camera?fps=30&width=64&height=48",
                "--out",
                str(out),
                "--duration",
                "20",
            ]
        )
    finally:
        timer.cancel()
    text = capsys.readouterr().out
    assert rc == 0 and "stopped by stop" in text, text
    s = load_session(out)
    last_end = s.frame_times_s[-1] + s.exposures_s[-1] + s.meta.imu.timeshift_cam_imu
    assert s.imu_times_s[-1] >= last_end + 0.2


def _camera_only_log(path: Path) -> None:
    """A finished recorder log with three frames and no IMU sample."""
    import cv2

    from rigs.camera_types import CameraFrame
    from rigs.reclog import RecLogWriter

    w = RecLogWriter(path, {"imu_url": "", "camera_url": "sim://camera"})
    png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1].tobytes()
    for i in range(3):
        frame = CameraFrame(i, np.zeros((8, 8), np.uint8), i * 10**8, 10**7, 5, "host")
        w.write_frame(frame, png, "png")
    w.finish()


def test_recover_refuses_a_session_without_imu_samples(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    log = tmp_path / "cam.mcap"
    _camera_only_log(log)
    before = tree_hashes(tmp_path)
    out, session = tmp_path / "r.mcap", tmp_path / "s"
    rc = main(["recover", str(log), "--out", str(out), "--session", str(session)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "holds no IMU samples" in err, err
    assert not session.exists() and debris(tmp_path) == []
    after = tree_hashes(tmp_path)
    assert out.is_file() and after.pop("r.mcap") and after == before  # the input unchanged
    # without --session, recovering the log alone is fine
    assert main(["recover", str(log), "--out", str(tmp_path / "r2.mcap")]) == 0
    with pytest.raises(RecorderLogError, match="no IMU samples"):
        log_to_session(log, tmp_path / "s2")
    assert not (tmp_path / "s2").exists()


def test_record_refuses_a_camera_only_session_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    argv = ["record", "--camera", "sim://camera?fps=30&width=64&height=48", "--out"]
    rc = main([*argv, str(tmp_path / "s"), "--duration", "30"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "needs gyro samples" in err, err
    assert list(tmp_path.iterdir()) == []
