"""The output guard's siblings: files a command writes beside its output are results too (an
existing one is replaced only with --force) and never one of its inputs."""

from __future__ import annotations

from pathlib import Path

import pytest

from blurtrack.cli import main
from blurtrack.io.guard import OutputRefusedError, check_output


def _session(root: Path) -> Path:
    s = root / "S"
    s.mkdir()
    (s / "session.yaml").write_text("format: blurtrack-session/1\n")
    return s


@pytest.mark.parametrize("sibling", [".summary.json", ".openvins.yaml", ".camera_info.yaml"])
def test_calibrate_does_not_overwrite_an_earlier_runs_sibling(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], sibling: str
) -> None:
    s = _session(tmp_path)
    old = tmp_path / f"calib{sibling}"
    old.write_text("an earlier result\n")
    rc = main(["calibrate", str(s), "--out", str(tmp_path / "calib.yaml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"'calib{sibling}' beside it exists" in err[0]
    assert old.read_text() == "an earlier result\n"
    assert not (tmp_path / "calib.yaml").exists()


def test_calibrate_never_writes_over_the_streak_table_it_reads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = _session(tmp_path)
    table = s / "streaks.parquet"
    table.write_bytes(b"PAR1 a table\n")
    rc = main(["calibrate", str(s), "--out", str(table), "--force"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "is also an input" in err[0]
    assert table.read_bytes() == b"PAR1 a table\n"


def test_a_sibling_that_is_an_input_is_refused_even_with_force(tmp_path: Path) -> None:
    inp = tmp_path / "c.summary.json"
    inp.write_text("{}")
    with pytest.raises(OutputRefusedError, match="is an input"):
        check_output(tmp_path / "c.yaml", force=True, inputs=[inp], siblings=["c.summary.json"])
    # negative control: the same sibling that is not an input is replaced with --force
    assert check_output(tmp_path / "c.yaml", force=True, siblings=["c.summary.json"])
