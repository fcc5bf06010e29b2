"""Frame-parallel detection and the time-shift scan's bad inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.detect.session import detect_session
from blurtrack.errors import DetectionError
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session


@pytest.fixture(scope="module")
def session_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("workers") / "s"
    write_synthetic_session(folder, n_frames=5, seed=4, timeshift_s=0.01)
    return folder


def test_workers_give_the_same_table_as_one_process(session_folder: Path) -> None:
    session = load_session(session_folder)
    one = detect_session(session, workers=1)
    seen: list[int] = []
    two = detect_session(session, workers=2, on_frame=lambda i, fs: seen.append(i))
    assert seen == list(range(5))  # progress in frame order
    pd.testing.assert_frame_equal(one.table, two.table, check_exact=True)
    assert one.summary == two.summary
    three = detect_session(session, workers=3, frames=range(1, 4))
    pd.testing.assert_frame_equal(
        three.table,
        detect_session(session, workers=1, frames=range(1, 4)).table,
        check_exact=True,
    )


def test_bad_worker_count_is_an_error(session_folder: Path) -> None:
    with pytest.raises(DetectionError, match="workers"):
        detect_session(load_session(session_folder), workers=0)


def test_timeshift_found_and_printed(session_folder: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "t.parquet"
    assert main(["detect", str(session_folder), "--out", str(out), "--workers", "2"]) == 0
    text = capsys.readouterr().out
    assert "camera-IMU time shift: +10." in text or "camera-IMU time shift: +9." in text


def test_all_zero_gyro_leaves_the_time_shift_undetermined(
    session_folder: Path, tmp_path: Path, capsys
) -> None:
    folder = tmp_path / "zero"
    import shutil

    shutil.copytree(session_folder, folder)
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    rows = [ln.split(",")[0] + ",0,0,0" for ln in lines[1:]]
    csv.write_text("\n".join([lines[0], *rows]) + "\n")
    res = detect_session(load_session(folder))
    assert res.summary["gyro_timeshift_status"] == "undetermined"
    assert res.summary["gyro_timeshift_s"] is None
    assert len(res.table) > 0 and np.all(res.table.llr_gyro == 0)
    assert main(["detect", str(folder), "--out", str(tmp_path / "z.parquet")]) == 0
    assert "camera-IMU time shift: undetermined" in capsys.readouterr().out
