"""Natural-scene calibration end to end: ``blurtrack calibrate`` on a simulated textured far
scene (known truth), the axis search overriding a wrong session.yaml, and every bad input
refused with one line and exit 2 (no calibration written)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.io.yamlio import read_yaml, write_yaml
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import NOMINAL_R_CAM_IMU, get_preset
from rigs.sim.writer import write_session

SMALL = dict(width=320, height=180, focal_px=250.0)


def _simulate(folder: Path, seed: int, frames: int, **changes) -> Path:
    preset = get_preset("realistic").replace(**SMALL, **changes)
    write_session(NaturalRig(preset, seed, frames), folder)
    return folder


@pytest.fixture(scope="module")
def natural(tmp_path_factory, shared_data) -> Path:
    return _simulate(tmp_path_factory.mktemp("natural") / "s", 5, 30)


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_calibrate_natural_session_recovers_the_truth(natural, tmp_path, capsys) -> None:
    s = _copy(natural, tmp_path / "s")
    meta = read_yaml(s / "session.yaml", "session.yaml")
    meta["imu"]["T_cam_imu"] = np.eye(4).tolist()  # a wrong guess: the images must decide
    write_yaml(s / "session.yaml", meta)
    out = tmp_path / "c" / "calib.yaml"
    assert main(["calibrate", str(s), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "axis search (feature tracks" in text
    summary = json.loads((tmp_path / "c" / "calib.summary.json").read_text())
    ax = summary["axes"]
    assert np.allclose(ax["winner"]["R_cam_imu"], NOMINAL_R_CAM_IMU)
    assert ax["margin"] > 2 and len(ax["candidates"]) == 24
    err = summary["error_vs_truth"]
    assert abs(err["timeshift_s"]) < 1e-3
    assert abs(err["readout_s"]) < 2e-3
    assert abs(err["fx"]) / summary["truth"]["fx"] < 0.02
    assert abs(err["cx"]) < 3 and abs(err["cy"]) < 3
    assert summary["features"]["tracks"] > 500
    assert out.exists()


def _refused(session: Path, tmp_path: Path, capsys, match: str) -> None:
    out = tmp_path / "c" / "calib.yaml"
    assert main(["calibrate", str(session), "--out", str(out), "--target", "natural"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err, err
    assert not out.exists()


def test_too_few_frames(natural, tmp_path, capsys) -> None:
    s = _copy(natural, tmp_path / "s")
    csv = s / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:4]) + "\n")
    _refused(s, tmp_path, capsys, "too few frames")


def test_textureless_frames(natural, tmp_path, capsys) -> None:
    import cv2

    s = _copy(natural, tmp_path / "s")
    for p in (s / "cam0" / "data").glob("*.png"):
        cv2.imwrite(str(p), np.full((180, 320), 128, np.uint8))
    _refused(s, tmp_path, capsys, "too few feature tracks")


def test_gyro_not_covering_the_frames(natural, tmp_path, capsys) -> None:
    s = _copy(natural, tmp_path / "s")
    csv = s / "imu0" / "data.csv"
    df = pd.read_csv(csv)
    df.iloc[:, 0] += 100_000_000_000
    df.to_csv(csv, index=False)
    _refused(s, tmp_path, capsys, "does not cover")


def test_foreign_gyro(natural, tmp_path, capsys) -> None:
    s = _copy(natural, tmp_path / "s")
    other = _simulate(tmp_path / "other", 11, 3)
    shutil.copy(other / "imu0" / "data.csv", s / "imu0" / "data.csv")
    _refused(s, tmp_path, capsys, "axis mapping")


def test_no_rotation(tmp_path, capsys, shared_data) -> None:
    s = _simulate(tmp_path / "still", 3, 8, motion_scale=(0.002, 0.002))
    _refused(s, tmp_path, capsys, "no rotation")


def test_thinning_spreads_each_pairs_tracks_over_the_image() -> None:
    from blurtrack.features.tracks import FeatureTracks
    from calib.natural.pipeline import THIN_GRID, thinned

    rng = np.random.default_rng(0)
    n_pairs, per_pair = 5, 120
    pts = []
    for _ in range(n_pairs):
        strong = rng.uniform([0, 0], [80, 60], (60, 2))  # the strongest corners: one corner
        rest = rng.uniform([0, 0], [640, 360], (per_pair - 60, 2))
        pts.append(np.vstack([strong, rest, [[0, 0], [640, 360]]]))
    p = np.vstack(pts)
    fa = np.repeat(np.arange(n_pairs), per_pair + 2)
    tr = FeatureTracks(
        fa, fa + 1, p, p + 1, np.zeros(len(p)), n_pairs + 1, np.full(n_pairs, per_pair + 2)
    )
    n_cells = THIN_GRID[0] * THIN_GRID[1]
    out = thinned(tr, n_pairs * n_cells)
    assert len(out) == n_pairs * n_cells
    for f in range(n_pairs):
        q = out.pts_a[out.frame_a == f]
        cells = {(int(x // (640 / THIN_GRID[0])), int(y // (360 / THIN_GRID[1]))) for x, y in q}
        assert len(cells) == n_cells  # one per cell
        # negative control: the strongest-first share would all sit in the corner
        first = tr.pts_a[tr.frame_a == f][:n_cells]
        assert np.all(first[:, 0] < 80) and np.all(first[:, 1] < 60)


def test_thinned_result_keeps_each_track_with_its_pseudo_streak() -> None:
    from typing import Any, cast

    from blurtrack.features.tracks import FeatureTracks
    from calib.natural.pipeline import NaturalResult, thinned, thinned_result, tracks_to_streaks

    rng = np.random.default_rng(1)
    n_pairs, per_pair = 6, 50
    p = rng.uniform([0, 0], [640, 360], (n_pairs * per_pair, 2))
    fa = np.repeat(np.arange(n_pairs), per_pair)
    tr = FeatureTracks(
        fa, fa + 1, p, p + 2, np.zeros(len(p)), n_pairs + 1, np.full(n_pairs, per_pair)
    )
    ts = np.arange(n_pairs + 1, dtype=np.int64) * 33_333_333
    streaks = tracks_to_streaks(tr, ts, np.full(n_pairs + 1, 10_000_000))
    none = cast(Any, None)
    nat = NaturalResult(none, none, tr, streaks, {"mode": "none"})
    out = thinned_result(nat, 60)
    assert len(out.tracks) == len(out.streaks) == 60
    np.testing.assert_array_equal(out.tracks.pts_a, thinned(tr, 60).pts_a)
    np.testing.assert_array_equal(out.streaks.start, out.tracks.pts_a)  # still paired
    np.testing.assert_array_equal(out.streaks.end, out.tracks.pts_b)
    np.testing.assert_array_equal(out.streaks.frame, out.tracks.frame_a)
    assert out.tracks.per_pair.tolist() == [10] * n_pairs
    assert thinned_result(nat, len(tr)) is nat  # nothing to thin
