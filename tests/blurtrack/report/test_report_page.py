"""The report's content: flagged streaks left out, worst frames drawn, fit table precision,
units and error/z columns, 2x figures, readable axes and overflow bins."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.report import figures
from blurtrack.report.html import decimals_for, fit_table, png_size
from blurtrack.report.metrics import stats

from .conftest import CLIPPED_OFFSET_PX, FIT, N_CLIPPED


def test_flagged_streaks_are_counted_apart_and_left_out(built_report: dict[str, Any]) -> None:
    s = built_report["summary"]
    table = built_report["table"]
    assert s["flagged"]["n_flagged"] == N_CLIPPED
    assert s["flagged"]["by_flag"]["clipped"]["n"] == N_CLIPPED
    # the clipped streaks' ends were moved by 40 px: they are the only large errors
    assert s["flagged"]["after"]["median_px"] > CLIPPED_OFFSET_PX / 2
    assert s["overall"]["after"]["n"] == len(table) - N_CLIPPED
    assert s["overall"]["after"]["p95_px"] < 5.0
    for v in s["motion_models"].values():
        assert v["n"] == len(table) - N_CLIPPED
    csv = pd.read_csv(built_report["out"] / "streak_errors.csv")
    after = csv[csv["variant"] == "after"]
    assert int(after["flagged"].sum()) == N_CLIPPED  # kept in the CSV, marked
    page = built_report["html"]
    assert "Flagged streaks (left out)" in page and f"{N_CLIPPED} of {len(table)}" in page


def test_overlays_show_the_worst_frames_first(built_report: dict[str, Any]) -> None:
    titles = re.findall(r"<h3>(Frame \d+ \(rank \d+)", built_report["html"])
    assert len(titles) == 2
    assert titles[0] == f"Frame {built_report['worst_frame']} (rank 1"


def test_progress_reaches_its_total(built_report: dict[str, Any]) -> None:
    calls = built_report["calls"]
    assert calls and calls[-1][0] == calls[-1][1]
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)


def test_fit_table_has_units_precision_error_and_z() -> None:
    page = fit_table(FIT)
    for head in ("unit", "sigma", "truth", "error", "z = error / sigma"):
        assert f"<th>{head}</th>" in page
    assert "<td>1000.34</td>" in page and "<td>1000.71</td>" in page  # not "1000"
    assert "<td>-0.37</td>" in page and "<td>-0.33</td>" in page  # error, z
    assert "<td>ms</td>" in page and "<td>-5.5761</td>" in page and "<td>0.0451</td>" in page
    assert "<td>mrad/s</td>" in page
    assert "<th>truth</th>" not in fit_table({**FIT, "truth": {}})  # no truth: no columns
    assert decimals_for(1.13) == 2 and decimals_for(4.51e-2) == 4 and decimals_for(None) is None


def test_z_beyond_three_is_marked() -> None:
    fit = {"values": {"fx": 1010.0}, "sigma": {"fx": 1.0}, "truth": {"fx": 1000.0}}
    assert "<td class='bad'>+10.00</td>" in fit_table(fit)


def test_figures_are_2x_and_shown_at_half_size(built_report: dict[str, Any]) -> None:
    page = built_report["html"]
    dims = re.findall(r"<img alt='[^']*' width='(\d+)' height='(\d+)'", page)
    assert len(dims) >= 8
    assert all(int(w) > 300 for w, _ in dims)
    png = figures.per_frame_plot(
        pd.DataFrame({"variant": "after", "frame": [0, 1], "mean_px": [0.1, 0.2]}), "t"
    )
    w, _h = png_size(png)
    assert w > 1500  # 11 in at 180 dpi, about 1900 px before the tight crop


def test_histogram_puts_the_tail_in_one_labelled_bin() -> None:
    e = np.concatenate([np.linspace(0, 1, 990), np.full(10, 50.0)])
    edges, hi = figures.histogram_bins(e)
    assert hi < 1.5 and edges[-2] == hi and edges[-1] > hi  # the 50 px tail: one last bin
    assert figures.histogram_cdf({"x": pd.DataFrame({"error_px": e})}, "t")[:4] == b"\x89PNG"


def test_position_map_uses_medians_and_counts() -> None:
    rng = np.random.default_rng(1)
    df = pd.DataFrame(
        {"start_x": rng.uniform(0, 160, 400), "start_y": rng.uniform(0, 90, 400)}
    ).assign(error_px=0.2)
    df.loc[df.index[:3], "error_px"] = 100.0  # a few outliers do not move the cells' median
    med, n = figures.cell_medians(df, 160, 90)
    assert n.sum() == 400 and med.shape == (9, 16)
    assert np.nanmax(med) == 0.2
    sparse = figures.cell_medians(df.iloc[:2], 160, 90)[0]
    assert np.isnan(sparse).all()  # fewer than MIN_CELL streaks: blank


def test_stats_helper_still_ignores_nan() -> None:
    assert stats(np.array([np.nan, 1.0]))["n"] == 1


def test_position_grid_coarsens_for_few_streaks() -> None:
    assert figures.grid_shape(100_000) == (16, 9)
    nx, ny = figures.grid_shape(52)
    assert 2 <= nx < 16 and 1 <= ny < 9 and 52 / (nx * ny) >= 4
