"""The report's figures explain themselves (issue 46): statistics in their own colours, no
lines across missing frames, a position map scaled from 0 without numbers in its cells, and a
histogram whose counts are log-scaled so one variant's spike does not flatten another."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import to_hex

from blurtrack.report import figures


def _errors(seed: int = 0, n: int = 400) -> dict[str, pd.DataFrame]:
    rng = np.random.default_rng(seed)

    def one(mu: float, sd: float) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "error_px": np.abs(rng.normal(mu, sd, n)),
                "start_x": rng.uniform(0, 160, n),
                "start_y": rng.uniform(0, 90, n),
            }
        )

    return {"before": one(3.0, 1.5), "after": one(0.15, 0.03)}


def test_contiguous_runs_split_at_missing_frames() -> None:
    runs = figures.contiguous_runs(np.array([5, 0, 1, 2, 6, 9]))
    assert [list(np.array([5, 0, 1, 2, 6, 9])[r]) for r in runs] == [[0, 1, 2], [5, 6], [9]]
    assert figures.contiguous_runs(np.array([], int)) == []


def test_per_frame_plot_has_markers_and_no_line_across_a_gap() -> None:
    fs = pd.DataFrame(
        {"variant": "after", "frame": [0, 1, 2, 5, 6, 9], "mean_px": [0.1, 0.2, 0.1, 0.3, 0.2, 0.1]}
    )
    fig = figures.per_frame_figure(fs, "t")
    lines = fig.axes[0].get_lines()
    assert [list(ln.get_xdata()) for ln in lines] == [[0, 1, 2], [5, 6], [9]]
    assert all(ln.get_marker() == "o" for ln in lines)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["after mean"]  # one legend entry per variant, not per run
    plt.close(fig)


def test_model_bars_do_not_reuse_the_variant_colours() -> None:
    summary = {"exact": {"mean_px": 0.2, "median_px": 0.1, "p95_px": 0.5}}
    fig = figures.model_bars_figure(summary, "t")
    ax = fig.axes[0]
    used = {to_hex(p.get_facecolor()) for p in ax.patches}
    assert len(used) == 3
    assert not used & {to_hex(c) for c in figures.COLORS[:2]}  # not before/after red and blue
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["mean", "median", "p95"]
    assert ax.get_title() == "t"
    plt.close(fig)


def test_position_map_scale_starts_at_zero_and_cells_hold_no_numbers() -> None:
    df = _errors()["after"]
    fig = figures.error_vs_position_figure(df, 160, 90, "after")
    ax = fig.axes[0]
    lo, hi = ax.get_images()[0].get_clim()
    assert lo == 0.0 and hi > 0.1
    inside = [t for t in ax.texts if t.get_transform() == ax.transData]
    assert inside == []  # no streak counts printed in the cells
    note = " ".join(t.get_text() for t in ax.texts)
    assert "streaks per coloured cell" in note and f"of {len(df)} streaks" in note
    assert ax.get_legend() is not None and ax.get_title()
    plt.close(fig)


def test_histogram_counts_are_log_scaled_and_labelled() -> None:
    errs = _errors()
    errs["after"] = errs["after"].assign(error_px=0.1)  # one tall spike
    fig = figures.histogram_cdf_figure(errs, "before vs after")
    hist, cdf = fig.axes
    assert hist.get_yscale() == "log" and cdf.get_xscale() == "log"
    (legend,) = fig.legends  # one legend for both panels
    assert [t.get_text() for t in legend.get_texts()][1] == "after"
    assert fig.get_suptitle() == "before vs after"
    plt.close(fig)
    assert figures.histogram_cdf(errs, "t")[:4] == b"\x89PNG"
