"""The rows' readout order decided by the frames, and detection in frames read bottom first."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from blurtrack.cli import main
from blurtrack.detect.frame import detect_frame
from blurtrack.detect.gyro.readout import (
    ReadoutOrder,
    readout_order,
    turned_calibration,
    turned_frame,
    turned_table,
)
from blurtrack.detect.gyro.timeshift import estimate_timeshift
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.detect.session.pipeline import detect_session
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session
from blurtrack.testing.turned import turn_session


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("readout")
    upright = root / "upright"
    assert main(["simulate", str(upright), "--preset", "realistic", "--frames", "4"]) == 0
    turned = root / "turned"
    turn_session(upright, turned)
    return {"upright": upright, "turned": turned}


def ok_ends(table: pd.DataFrame) -> np.ndarray:
    """``(N, 4)`` the ``quality_ok`` streaks' start and end (frame-major order)."""
    ok = table[table["quality_ok"]]
    return ok[["frame", "start_x", "start_y", "end_x", "end_y"]].to_numpy(float)


def right_ok_fraction(table: pd.DataFrame, truth: dict[str, Any]) -> tuple[float, int]:
    """Of the ``quality_ok`` streaks, the share with both ends within 2 px of one true
    streak's (either way round), and how many there are."""
    right = total = 0
    for fr in truth["frames"]:
        rows = table[(table["frame"] == fr["index"]) & table["quality_ok"]]
        S = np.array([s["start"] for s in fr["streaks"]])
        E = np.array([s["end"] for s in fr["streaks"]])
        for s0, s1, e0, e1 in rows[["start_x", "start_y", "end_x", "end_y"]].to_numpy():
            same = np.maximum(np.hypot(*(S - [s0, s1]).T), np.hypot(*(E - [e0, e1]).T))
            swap = np.maximum(np.hypot(*(S - [e0, e1]).T), np.hypot(*(E - [s0, s1]).T))
            right += int(np.min(np.minimum(same, swap)) <= 2.0)
            total += 1
    return right / max(total, 1), total


def test_upright_frames_read_the_top_row_first(sessions: dict[str, Path]) -> None:
    res = detect_session(load_session(sessions["upright"]), workers=1)
    order = res.summary["gyro_readout_order"]
    assert order["status"] == "top_first"
    assert order["llr_top_first"] > DetectParams().timeshift.readout_order_llr
    assert "message" not in order


def test_frames_read_bottom_first_are_detected_turned(sessions: dict[str, Path]) -> None:
    upright = detect_session(load_session(sessions["upright"]), workers=1)
    session = load_session(sessions["turned"])
    res = detect_session(session, workers=1)
    order = res.summary["gyro_readout_order"]
    assert order["status"] == "bottom_first"
    assert order["llr_top_first"] < -DetectParams().timeshift.readout_order_llr
    assert "bottom to top" in order["message"]
    # The table is in the stored frames' pixels, and right against their (turned) truth.
    share, n = right_ok_fraction(res.table, session.truth)
    assert n > 0.9 * int(upright.table["quality_ok"].sum())
    assert share > 0.99
    # The same streaks as the upright session's, turned.
    w, h = session.meta.camera.resolution
    mine = ok_ends(turned_table(res.table, (w, h)))
    theirs = ok_ends(upright.table)
    for fr in np.unique(theirs[:, 0]):
        a, b = mine[mine[:, 0] == fr, 1:], theirs[theirs[:, 0] == fr, 1:]
        d = np.min(np.abs(a[:, None, :] - b[None, :, :]).max(axis=2), axis=0)
        assert np.median(d) < 0.05
    assert res.summary["gyro_direction"]["status"] == "consistent"


def test_without_the_check_bottom_first_frames_lose_their_trusted_streaks(
    sessions: dict[str, Path],
) -> None:
    # Negative control: the session's order taken on trust.
    p = DetectParams()
    off = replace(p, timeshift=replace(p.timeshift, readout_order_check=False))
    session = load_session(sessions["turned"])
    res = detect_session(session, off, workers=1)
    assert res.summary["gyro_readout_order"] is None
    checked = detect_session(session, workers=1)
    assert int(res.table["quality_ok"].sum()) < 0.8 * int(checked.table["quality_ok"].sum())


def test_the_cli_says_the_frames_read_bottom_first(
    sessions: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "t.parquet"
    assert main(["detect", str(sessions["turned"]), "--out", str(out), "--workers", "1"]) == 0
    got = capsys.readouterr()
    assert "warning: the frames' streaks fit rows read bottom to top" in got.err
    assert "  rows read: bottom first (log-likelihood ratio -" in got.out
    assert out.is_file()


def test_a_global_shutter_is_not_checked(tmp_path: Path) -> None:
    write_synthetic_session(tmp_path / "s", n_frames=8, seed=5, grid=(8, 6), amplitude_radps=3.0)
    res = detect_session(load_session(tmp_path / "s"), workers=1)
    assert res.summary["gyro_timeshift_status"] == "found"
    assert res.summary["gyro_readout_order"]["status"] == "global"


def test_turning_the_calibration_turns_the_rates_and_undoes_itself() -> None:
    # The camera's own turn is tests/blurtrack/geometry/test_geometry_camera_turned.py's.
    cam = Camera(resolution=(640, 480), intrinsics=(500.0, 510.0, 300.0, 250.0), readout_s=0.02)
    R = cv2.Rodrigues(np.array([0.1, -0.2, 0.3]))[0]
    calib = Calibration(camera=cam, R_cam_imu=R, timeshift_cam_imu_s=0.004)
    turned = turned_calibration(calib)
    omega_imu = np.array([0.3, -1.2, 0.5])
    # A rate about the camera's x and y axes runs the other way in the turned camera.
    np.testing.assert_allclose(
        turned.R_cam_imu @ omega_imu, [-1.0, -1.0, 1.0] * (R @ omega_imu), atol=1e-9
    )
    assert turned.camera.intrinsics[2:] == (339.0, 229.0)
    assert turned.timeshift_cam_imu_s == calib.timeshift_cam_imu_s
    back = turned_calibration(turned)
    assert back.camera == calib.camera
    np.testing.assert_allclose(back.R_cam_imu, calib.R_cam_imu, atol=1e-9)


def test_turning_a_table_and_a_frame_twice_gives_them_back(sessions: dict[str, Path]) -> None:
    res = detect_session(load_session(sessions["upright"]), gyro="off", workers=1)
    table = res.table
    once = turned_table(table, (1280, 720))
    assert once["start_x"].iloc[0] == pytest.approx(1279.0 - table["start_x"].iloc[0])
    assert once["mid_y"].iloc[0] == pytest.approx(719.0 - table["mid_y"].iloc[0])
    np.testing.assert_allclose(
        np.asarray(once["centerline"].iloc[0])[0],
        [1279.0, 719.0] - np.asarray(table["centerline"].iloc[0]).reshape(-1, 2)[0],
    )
    twice = turned_table(once, (1280, 720))
    for col in ("start_x", "start_y", "end_x", "end_y", "mid_x", "mid_y"):
        np.testing.assert_allclose(twice[col], table[col], atol=1e-9)
    fs = res.frames[0]
    back = turned_frame(turned_frame(fs))
    np.testing.assert_allclose(back.end_a, fs.end_a)
    np.testing.assert_allclose(back.points[0], fs.points[0])
    assert ReadoutOrder("undetermined").usable


def test_a_global_shutter_said_to_roll_is_not_turned(tmp_path: Path) -> None:
    # Neither order fits a readout the sensor does not have: undetermined, never turned.
    folder = tmp_path / "clean"
    assert main(["simulate", str(folder), "--preset", "clean", "--frames", "6"]) == 0
    meta = yaml.safe_load((folder / "session.yaml").read_text())
    assert meta["camera"]["readout_s"] == 0.0
    meta["camera"]["readout_s"] = 0.03
    (folder / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    res = detect_session(load_session(folder), workers=1)
    order = res.summary["gyro_readout_order"]
    assert order["status"] == "undetermined"
    assert abs(order["llr_top_first"]) < DetectParams().timeshift.readout_order_llr


def test_a_gyro_reading_zero_decides_no_order(sessions: dict[str, Path], tmp_path: Path) -> None:
    folder = tmp_path / "zero"
    shutil.copytree(sessions["upright"], folder)
    csv = folder / "imu0" / "data.csv"
    head, *rows = csv.read_text().splitlines()
    zeroed = [",".join([r.split(",")[0], "0", "0", "0", *r.split(",")[4:]]) for r in rows]
    csv.write_text("\n".join([head, *zeroed]) + "\n")
    # The detect command does not use such a gyro (its motion contradicts the images'), so
    # the order is not checked at all.
    res = detect_session(load_session(folder), workers=1)
    assert res.summary["gyro_timeshift_status"] == "gyro not used"
    assert res.summary["gyro_readout_order"] is None
    # Given it, the check itself decides nothing: both scans are flat, the same least cost
    # either way round.
    s = load_session(folder)
    found = [detect_frame(s.read_image(k)) for k in range(len(s.frames))]
    timings = [
        FrameTiming(float(t), float(e)) for t, e in zip(s.frame_times_s, s.exposures_s, strict=True)
    ]
    calib, trace = s.initial_calibration(), s.gyro()
    scan = estimate_timeshift(found, timings, calib, trace)
    assert scan is not None and scan.status == "undetermined"
    order = readout_order(found, timings, calib, trace, scan)
    assert order.status == "undetermined"
    assert order.as_dict()["llr_top_first"] == pytest.approx(0.0, abs=1.0)
