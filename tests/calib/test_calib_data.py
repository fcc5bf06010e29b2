"""calib.data.streaks_from_table: which streaks of a detection table calibration keeps."""

from __future__ import annotations

import numpy as np
import pandas as pd

from calib.data import streaks_from_table


def _table(n: int, rng: np.random.Generator) -> tuple[pd.DataFrame, pd.DataFrame]:
    frames = pd.DataFrame(
        {"timestamp_ns": np.arange(3, dtype=np.int64) * 50_000_000, "exposure_ns": [20_000_000] * 3}
    )
    frame = rng.integers(0, 3, n)
    start = rng.uniform(10, 500, (n, 2))
    table = pd.DataFrame(
        {
            "frame": frame,
            "timestamp_ns": frames["timestamp_ns"].to_numpy()[frame],
            "streak_id": np.arange(n),
            "start_x": start[:, 0],
            "start_y": start[:, 1],
            "end_x": start[:, 0] + 10.0,
            "end_y": start[:, 1] + 3.0,
            "mid_x": start[:, 0] + 5.0,
            "mid_y": start[:, 1] + 1.5,
            "clipped": rng.random(n) < 0.2,
            "saturated": rng.random(n) < 0.2,
            "merged": rng.random(n) < 0.2,
        }
    )
    return table, frames


def test_streaks_not_quality_ok_are_left_out_and_counted() -> None:
    rng = np.random.default_rng(3)
    table, frames = _table(200, rng)
    flagged = (table.clipped | table.merged).to_numpy()
    table["quality_ok"] = rng.random(len(table)) < 0.7
    s = streaks_from_table(table, frames)
    kept = ~flagged & table["quality_ok"].to_numpy()
    assert np.array_equal(s.streak_id, table["streak_id"].to_numpy()[kept])
    # A saturated core alone does not leave a quality_ok streak out (issue 45) ...
    assert np.any(table.saturated.to_numpy() & kept)
    # ... and counted: only those that no other dropped flag already removed.
    assert s.dropped_quality == int(np.sum(~flagged & ~table["quality_ok"].to_numpy())) > 0


def test_tables_without_quality_ok_and_unfiltered_use_keep_their_streaks() -> None:
    rng = np.random.default_rng(4)
    table, frames = _table(100, rng)
    flagged = (table.clipped | table.saturated | table.merged).to_numpy()
    s = streaks_from_table(table, frames)  # an older table: the core flags only
    assert np.array_equal(s.streak_id, table["streak_id"].to_numpy()[~flagged])
    assert s.dropped_quality == 0
    table["quality_ok"] = False
    every = streaks_from_table(table, frames, drop_flagged=False)
    assert len(every.frame) == len(table) and every.dropped_quality == 0
