"""``blurtrack predict``: heat maps and trajectory table of a session, coverage errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.errors import CoverageError, SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import write_calibration
from blurtrack.io.session import SessionMeta, SessionWriter, load_session
from blurtrack.synth.predict import predict_session

CAM = Camera((80, 60), (70.0, 70.0, 39.5, 29.5), readout_s=0.01)


def make_session(folder: Path, frame_ns: list[int]) -> Path:
    t_ns = np.arange(0, 400_000_000, 5_000_000)
    t = t_ns * 1e-9
    w = np.stack([np.sin(7 * t), np.cos(5 * t), 0.3 * np.sin(3 * t)], axis=1)
    with SessionWriter(folder, SessionMeta(CAM, target_kind="natural")) as wr:
        for ts in frame_ns:
            wr.add_frame(ts, np.zeros((60, 80), np.uint8), 20_000_000)
        wr.add_imu(t_ns, w)
    return folder


def test_predict_matches_model_and_writes_table(tmp_path: Path) -> None:
    s = load_session(make_session(tmp_path / "s", [50_000_000, 150_000_000]))
    calib = Calibration(CAM.scaled(2.0))  # calibrated at twice the size: scaled down
    res = predict_session(s, calib, tmp_path / "out", stride=4, n_t=8, grid=(5, 4))
    assert res.written == [50_000_000, 150_000_000] and res.skipped == []
    heat = np.load(tmp_path / "out" / "heat" / "150000000.npy", allow_pickle=False)
    model = BlurModel(Calibration(CAM.scaled(2.0).scaled(0.5)), s.gyro())
    want, _ = model.heat_maps(0.15, 0.02, 8, None, 4)
    np.testing.assert_allclose(heat, want, atol=1e-4)
    tab = pd.read_parquet(tmp_path / "out" / "trajectories.parquet")
    assert list(tab.columns) == ["timestamp_ns", "x", "y", "tau", "qx", "qy"]
    assert len(tab) == 2 * 5 * 4 * 8
    first = tab[(tab.timestamp_ns == 150_000_000) & (tab.tau == 0.0)]
    x, y = first.x.to_numpy().astype(int), first.y.to_numpy().astype(int)
    np.testing.assert_allclose(first.qx, heat[0, y, x], atol=1e-3)
    np.testing.assert_allclose(first.qy, heat[1, y, x], atol=1e-3)


def test_uncovered_frames_refused_or_skipped(tmp_path: Path, capsys) -> None:
    folder = make_session(tmp_path / "s", [100_000_000, 390_000_000, 500_000_000])
    s = load_session(folder)
    with pytest.raises(CoverageError, match="2 of 3 frames.*390000000, 500000000"):
        predict_session(s, Calibration(CAM), tmp_path / "out")
    assert not (tmp_path / "out").exists()
    res = predict_session(s, Calibration(CAM), tmp_path / "out", skip_uncovered=True)
    assert res.written == [100_000_000] and res.skipped == [390_000_000, 500_000_000]
    with pytest.raises(SynthesisError, match="aspect"):
        predict_session(s, Calibration(Camera((80, 80), (70.0, 70.0, 39.5, 39.5))), tmp_path)
    cal = tmp_path / "cal.yaml"
    write_calibration(Calibration(CAM), cal)
    assert main(["predict", str(folder), "--calib", str(cal), "--out", str(tmp_path / "c")]) == 2
    assert "does not cover 2 of 3 frames" in capsys.readouterr().err
    assert (
        main(
            [
                "predict",
                str(folder),
                "--calib",
                str(cal),
                "--out",
                str(tmp_path / "c"),
                "--skip-uncovered",
            ]
        )
        == 0
    )
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert summary["predicted"] == 1 and summary["skipped_timestamps_ns"] == [
        390_000_000,
        500_000_000,
    ]
