"""``detect`` writes SESSION/streaks.parquet; ``report`` detects first when it is missing;
progress bars appear only on a terminal and never with --quiet."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.cli import progress as progress_mod
from blurtrack.io.calibration import write_calibration
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session


@pytest.fixture()
def session(tmp_path: Path) -> Path:
    folder = tmp_path / "session"
    write_synthetic_session(folder, n_frames=3, seed=5)
    return folder


def test_detect_writes_into_the_session_and_keeps_it(
    session: Path, capsys: pytest.CaptureFixture
) -> None:
    assert main(["detect", str(session), "--quiet"]) == 0
    table = session / "streaks.parquet"
    assert len(pd.read_parquet(table)) > 0
    summary = json.loads((session / "derived" / "streaks.summary.json").read_text())
    assert summary["table"] == str(table)
    assert not (session / "streaks.summary.json").exists()  # only reserved names in a session
    capsys.readouterr()
    before = table.stat().st_mtime_ns
    assert main(["detect", str(session)]) == 2
    assert "--force" in capsys.readouterr().err
    assert table.stat().st_mtime_ns == before
    assert main(["detect", str(session), "--force", "--quiet"]) == 0


def test_report_detects_first_and_says_so(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    calib = tmp_path / "calib.yaml"
    write_calibration(load_session(session).initial_calibration(), calib)
    out = tmp_path / "report"
    argv = ["report", str(session), "--calib", str(calib), "--out", str(out), "--overlays", "1"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    assert "no streak table" in cap.out and "detecting" in cap.out
    assert (session / "streaks.parquet").is_file()
    assert (out / "report.html").is_file()
    # a second report reads the table it left behind, without detecting again
    assert main([*argv, "--overlays", "0", "--force"]) == 0
    assert "detecting" not in capsys.readouterr().out


def test_explicit_missing_table_is_one_line_error(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    calib = tmp_path / "calib.yaml"
    write_calibration(load_session(session).initial_calibration(), calib)
    argv = ["report", str(session), "--calib", str(calib), "--out", str(tmp_path / "r")]
    assert main([*argv, "--streaks", str(tmp_path / "nope.parquet")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.parquet" in err[0]
    assert not (session / "streaks.parquet").exists()


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_only_on_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(progress_mod, "DELAY_S", 0.0)
    pipe = io.StringIO()
    monkeypatch.setattr("sys.stderr", pipe)
    with progress_mod.Progress("work", "frame") as bar:
        for i in range(5):
            bar(i + 1, 5)
    assert pipe.getvalue() == ""  # not a terminal: silent
    tty = _Tty()
    monkeypatch.setattr("sys.stderr", tty)
    with progress_mod.Progress("work", "frame", quiet=True) as bar:
        bar(1, 5)
    assert tty.getvalue() == ""  # --quiet
    with progress_mod.Progress("work", "frame") as bar:
        for i in range(5):
            bar(i + 1, 5)
    text = tty.getvalue()
    assert "work" in text and "5/5" in text and "<" in text  # count and ETA


@pytest.mark.parametrize(
    ("frames", "says"),
    [
        ("5:2", "selects none of the session's 3 frames"),
        ("7:", "selects none of the session's 3 frames"),
        ("1", "must look like A:B"),
        ("a:b", "must look like A:B"),
    ],
)
def test_a_frame_range_that_selects_nothing_is_one_line_error(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture, frames: str, says: str
) -> None:
    out = tmp_path / "out.parquet"
    assert main(["detect", str(session), "--out", str(out), f"--frames={frames}", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not out.exists()
    # A range that selects frames detects those only (the negative control).
    assert main(["detect", str(session), "--out", str(out), "--frames=1:3", "--quiet"]) == 0
    assert set(pd.read_parquet(out)["frame"]) <= {1, 2}


def test_frames_whose_prediction_is_off_are_named(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The exact rig lowers no frame's tolerance (no line); where the check measured frames
    # off (here forced through the summary's own helper), the command names them.
    assert main(["detect", str(session), "--out", str(tmp_path / "a.parquet")]) == 0
    out = capsys.readouterr().out
    assert "gyro check:" not in out
    from blurtrack.detect.session import pipeline

    def off(found, idx, p):
        return {
            "gyro_trust_model_error_px": {"median": 0.2, "p90": 0.9, "max": 1.3},
            "gyro_trust_lowered_frames": [1, 2],
        }

    monkeypatch.setattr(pipeline, "_model_errors", off)
    assert main(["detect", str(session), "--out", str(tmp_path / "b.parquet")]) == 0
    out = capsys.readouterr().out
    assert "gyro check: the prediction misses 2 of" in out
    assert "by more than 0.50 px (up to 1.30 px); their tolerances lowered: frames [1, 2]" in out


def test_detect_says_when_quality_ok_comes_from_the_images_alone(
    session: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from blurtrack.cli.photos import IMAGE_ONLY_NOTE

    assert main(["detect", str(session), "--out", str(tmp_path / "a.parquet"), "--quiet"]) == 0
    assert IMAGE_ONLY_NOTE not in capsys.readouterr().out  # the gyro checked the ends
    args = ["detect", str(session), "--out", str(tmp_path / "b.parquet"), "--gyro", "off"]
    assert main([*args, "--quiet"]) == 0
    assert f"note: {IMAGE_ONLY_NOTE}" in capsys.readouterr().out
