"""The report's shape-consistency summary (blurtrack.report.shape)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from blurtrack.report.shape import shape_section, shape_summary


def _table() -> pd.DataFrame:
    rng = np.random.default_rng(5)
    dev = np.concatenate([rng.uniform(0.0, 1.0, 40), [12.0, 15.0], [np.nan] * 3])
    frame = np.repeat([0, 1, 2], 15)
    return pd.DataFrame({"frame": frame, "shape_deviation_px": dev, "quality_ok": dev < 3.0})


def test_summary_percentiles_follow_the_deviations() -> None:
    t = _table()
    s = shape_summary(t)
    assert s is not None
    dev = t["shape_deviation_px"].to_numpy()
    fin = dev[np.isfinite(dev)]
    assert s["overall"]["n"] == fin.size == 42 and s["overall"]["n_streaks"] == 45
    assert s["overall"]["p50_px"] == np.percentile(fin, 50)
    # The two outliers (a chain, a fragment) lift the 99th percentile, not the kept streaks'.
    assert s["overall"]["p99_px"] > 10.0 > 1.0 >= s["overall"]["kept"]["p99_px"]
    assert s["overall"]["quality_ok"] == 40
    last = s["per_frame"][-1]
    assert last["frame"] == 2 and last["n"] == 12 and last["n_streaks"] == 15
    html = "".join(shape_section(s))
    assert "Shape consistency" in html and html.count("<tr><td>") == 2 + 3


def test_tables_without_the_column_or_a_consensus_have_no_section() -> None:
    t = _table()
    assert shape_summary(t.drop(columns="shape_deviation_px")) is None
    t["shape_deviation_px"] = np.nan
    assert shape_summary(t) is None
    assert shape_section(None) == []
