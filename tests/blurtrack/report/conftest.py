"""A small report built once per test session: mini laser-grid session, true streaks with a
few of them flagged ``clipped`` and moved far off, and a fit summary with known truth."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from blurtrack.io import streaks as streak_table
from blurtrack.io.session import load_session
from blurtrack.report.build import build_report
from blurtrack.testing.mini_session import write_synthetic_session

#: Streaks marked clipped in the fixture, and how far their ends are moved (px).
N_CLIPPED = 6
CLIPPED_OFFSET_PX = 40.0

FIT = {
    "status": "ok",
    "iterations": 7,
    "n_outliers": 0,
    "n_flipped": 0,
    "residuals": "tracks",
    "values": {"timeshift_s": -0.0055761, "fx": 1000.34, "bias_x": 0.001071},
    "sigma": {"timeshift_s": 4.51e-5, "fx": 1.13, "bias_x": 5.12e-4},
    "truth": {"timeshift_s": -0.005689, "fx": 1000.71, "bias_x": 0.001526},
    "holdout_inliers": {"n": 10, "mean_px": 0.2, "median_px": 0.15, "p95_px": 0.4},
    "warnings": [],
}


@pytest.fixture(scope="session")
def built_report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("report")
    folder = root / "session"
    write_synthetic_session(folder, n_frames=4, seed=2)
    session = load_session(folder)
    table = streak_table.from_truth(session.truth).copy()
    rng = np.random.default_rng(0)
    bad = rng.choice(len(table), N_CLIPPED, replace=False)
    table.loc[table.index[bad], "clipped"] = True
    table.loc[table.index[bad], "end_x"] += CLIPPED_OFFSET_PX
    # one frame much worse than the others: the overlays must show it first
    worst = int(table["frame"].max())
    sel = (table["frame"] == worst).to_numpy() & ~table["clipped"].to_numpy()
    table.loc[sel, "end_y"] += 2.0
    calib = session.initial_calibration()
    out = root / "out"
    calls: list[tuple[int, int]] = []
    summary = build_report(
        session,
        streak_table.validate(table),
        calib.with_(timeshift_cam_imu_s=0.002),
        calib,
        out,
        fit_summary=FIT,
        n_overlays=2,
        progress=lambda d, t: calls.append((d, t)),
    )
    return {
        "out": out,
        "summary": summary,
        "table": table,
        "worst_frame": worst,
        "calls": calls,
        "html": (out / "report.html").read_text(encoding="utf-8"),
    }
