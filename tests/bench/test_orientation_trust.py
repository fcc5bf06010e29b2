"""bench/orientation_trust.py: the matching of detections to true starts, and the report."""

from __future__ import annotations

import numpy as np
import pandas as pd

from blurtrack.testing.bench_script import load_bench_script


def _table(rows: list[tuple[float, float, float, float, float, bool]]) -> pd.DataFrame:
    cols = ["start_x", "start_y", "end_x", "end_y", "orientation_confidence", "quality_ok"]
    df = pd.DataFrame(rows, columns=cols)
    df.insert(0, "frame", 0)
    return df


def test_starts_are_matched_either_way_round_within_the_gate() -> None:
    bench = load_bench_script("orientation_trust")
    truth = {
        "frames": [
            {
                "index": 0,
                "streaks": [
                    {"start": [10.0, 10.0], "end": [40.0, 10.0]},
                    {"start": [10.0, 50.0], "end": [40.0, 50.0]},
                    {"start": [80.0, 80.0], "end": [82.0, 80.0]},  # too short to orient
                ],
            }
        ]
    }
    table = _table(
        [
            (10.5, 10.0, 40.0, 10.5, 0.99, True),  # right
            (40.0, 50.0, 10.0, 50.0, 0.97, False),  # backwards
            (10.0, 53.0, 40.0, 50.0, 0.9, True),  # an end 3 px off: not matched
            (80.0, 80.0, 82.0, 80.0, 0.9, True),  # the short one: not counted
        ]
    )
    conf, right, ok = bench.oriented_against_truth(table, truth)
    np.testing.assert_allclose(conf, [0.99, 0.97])
    assert right.tolist() == [True, False]
    assert ok.tolist() == [True, False]


def test_the_report_counts_confident_wrong_starts_and_the_log_loss() -> None:
    bench = load_bench_script("orientation_trust")
    conf = np.array([0.99, 0.97, 0.6, 0.9999])
    right = np.array([True, False, True, True])
    got = bench.calibration(conf, right)
    assert got["n"] == 4 and got["wrong_pct"] == 25.0
    assert got["wrong_at_0_95"] == 1 and got["wrong_at_0_99"] == 0
    assert got["bins"]["[0.95, 0.99)"] == [1, 1]
    assert got["bins"]["[0.9999, 1.0)"] == [1, 0]
    expect = -np.mean(np.log([0.99, 0.03, 0.6, 0.9999]))
    assert abs(got["log_loss"] - round(expect, 4)) < 1e-12
    assert bench.calibration(np.zeros(0), np.zeros(0, bool)) == {"n": 0}
