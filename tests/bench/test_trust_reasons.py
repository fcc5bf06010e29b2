"""bench/trust_reasons.py: the stricter subsets of quality_ok by the gyro's vector residual."""

from __future__ import annotations

import numpy as np
import pandas as pd

from blurtrack.testing.bench_script import load_bench_script


def test_residual_caps_count_the_subsets_against_the_truth() -> None:
    bench = load_bench_script("trust_reasons")
    # Four true streaks in frame 0; five quality_ok detections (one wrong, one unchecked)
    # and one refused.
    table = pd.DataFrame(
        {
            "frame": [0, 0, 0, 0, 0, 0],
            "truth_id": [0, 1, 2, 3, 3, -1],
            "quality_ok": [True, True, True, True, False, True],
            "right": [True, True, True, True, True, False],
            "gyro_residual_px": [0.2, 0.9, 1.4, np.nan, 0.1, 0.6],
        }
    )
    got = bench.residual_caps(table, 4, (1.5, 1.0, 0.5))
    assert got["1.5"] == {
        "detections": 4,
        "wrong": 1,
        "ok_precision_pct": 75.0,
        "ok_coverage_pct": 75.0,
    }
    assert got["1"] == {
        "detections": 3,
        "wrong": 1,
        "ok_precision_pct": 66.67,
        "ok_coverage_pct": 50.0,
    }
    assert got["0.5"] == {
        "detections": 1,
        "wrong": 0,
        "ok_precision_pct": 100.0,
        "ok_coverage_pct": 25.0,
    }
