"""``blurtrack detect PHOTO ... --out FILE``: photographs' table, summary and source
pictures; the session options a photograph has nothing for, and bad files, refused in one line
before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.testing.mini_session import write_synthetic_session
from tests.blurtrack.detect.test_detect_photos import write_photos


def test_photographs_give_a_table_a_summary_and_pictures(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    photos = write_photos(tmp_path / "in")
    out = tmp_path / "res" / "t.parquet"
    pics = tmp_path / "pics"
    args = ["detect", *map(str, photos), "--out", str(out), "--overlay", str(pics)]
    assert main(args) == 0
    table = pd.read_parquet(out)
    summary = json.loads(out.with_name("t.summary.json").read_text())
    assert summary["streaks"] == len(table) and summary["gyro"] == "off"
    assert summary["quality_ok"] == int(table["quality_ok"].sum()) > 0
    assert [p["photo"] for p in summary["photos"]] == [str(p) for p in photos]
    for k, p in enumerate(summary["photos"]):
        assert p["streaks"] == int((table["frame"] == k).sum())
        pic = cv2.imread(p["overlay"])
        assert Path(p["overlay"]) == pics / f"{photos[k].stem}.png"
        assert pic.shape[:2] == (p["height_px"], p["width_px"])
    said = capsys.readouterr().out
    assert f"in 3 photograph(s) -> {out}" in said and "quality_ok" in said
    # Again without --force: refused, nothing rewritten.
    before = out.stat().st_mtime_ns
    assert main(args) == 2
    assert "--force" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == before
    assert main([*args, "--force"]) == 0


def test_one_photograph_with_a_picture_file(tmp_path: Path) -> None:
    photo = write_photos(tmp_path / "in")[0]
    pic = tmp_path / "one.png"
    out = tmp_path / "t.parquet"
    assert main(["detect", str(photo), "--out", str(out), "--overlay", str(pic)]) == 0
    assert cv2.imread(str(pic)) is not None


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        ([], "photographs need --out"),
        (["--out", "T", "--gyro", "on"], "photographs have no gyro"),
        (["--out", "T", "--frames", "0:1"], "--frames"),
    ],
)
def test_session_options_are_refused_for_photographs(
    tmp_path: Path, capsys: pytest.CaptureFixture, extra: list[str], said: str
) -> None:
    photo = write_photos(tmp_path / "in")[0]
    extra = [str(tmp_path / "t.parquet") if a == "T" else a for a in extra]
    assert main(["detect", str(photo), *extra]) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t.parquet").exists()


def test_bad_inputs_are_one_line_and_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    photos = write_photos(tmp_path / "in")
    bad = tmp_path / "in" / "broken.jpg"
    bad.write_bytes(b"\xff\xd8\xff garbage")
    out = tmp_path / "t.parquet"
    assert main(["detect", str(photos[0]), str(bad), "--out", str(out)]) == 2
    assert "broken.jpg" in capsys.readouterr().err
    assert not out.exists() and not out.with_name("t.summary.json").exists()
    # The table may not replace a photograph, even with --force.
    assert main(["detect", str(photos[0]), "--out", str(photos[0]), "--force"]) == 2
    assert "input" in capsys.readouterr().err
    assert cv2.imread(str(photos[0])) is not None
    # A session and photographs together, or two sessions: refused.
    session = tmp_path / "session"
    write_synthetic_session(session, n_frames=2, seed=3)
    assert main(["detect", str(session), str(photos[0]), "--out", str(out)]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["detect", str(session), str(session), "--out", str(out)]) == 2
    assert "one session folder" in capsys.readouterr().err
    # Two photographs of one name cannot share the picture folder.
    twin = tmp_path / "other" / photos[0].name
    twin.parent.mkdir()
    twin.write_bytes(photos[0].read_bytes())
    pics = tmp_path / "pics"
    twins = [str(photos[0]), str(twin)]
    assert main(["detect", *twins, "--out", str(out), "--overlay", str(pics)]) == 2
    assert "share the picture" in capsys.readouterr().err
    assert not out.exists()
