"""Report figures (matplotlib, Agg backend) returned as PNG bytes at twice screen resolution.

Every figure is drawn at :data:`DPI` (2 × the 90 dpi it is shown at, see
:func:`blurtrack.report.html.render`), so it stays sharp on high-density screens. Error axes are
linear or plain logarithmic with errors below :data:`FLOOR_PX` drawn at the floor (no ``symlog``
kink); histograms put everything beyond their range into one labelled last bin.
"""

from __future__ import annotations

import io
from collections.abc import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.patches import Patch, Rectangle
from matplotlib.ticker import FuncFormatter, LogFormatter, LogLocator, MaxNLocator

#: One colour per compared variant (before, after, motion models...), in order.
COLORS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e")
#: Colours of the summary statistics (mean, median, p95): none of them is a variant's colour,
#: so a statistic is never read as "before" or "after".
STAT_COLORS = {"mean_px": "#8c564b", "median_px": "#e6ab02", "p95_px": "#17becf"}
#: Resolution of the PNGs (2× the page's 90 dpi).
DPI = 180
#: Smallest error drawn on a log axis (px); smaller errors are drawn at the floor.
FLOOR_PX = 1e-3
#: Position-map cells with fewer streaks than this are left blank.
MIN_CELL = 3
#: Position-map cells with a median but fewer streaks than this are hatched (a less sure median).
FEW_CELL = 10


def _png(fig: plt.Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _finite(df: pd.DataFrame) -> pd.DataFrame:
    return df[np.isfinite(df["error_px"].to_numpy())]


def _px_ticks(v: float, _pos: object) -> str:
    return f"{v:g}"


class _PlainLogFormatter(LogFormatter):
    """Matplotlib's choice of which minor log ticks to label (none over many decades, 2, 3, 5
    over about one), written as plain decimals (0.3, 2) instead of 3 × 10⁻¹."""

    def _num_to_string(self, x: float, vmin: float, vmax: float) -> str:
        return f"{x:g}"


def _log_px_axis(set_scale: Callable[..., None], axis: matplotlib.axis.Axis) -> None:
    """A log axis in px with plain decimal tick labels (0.01, 0.1, 1, 10)."""
    set_scale("log")
    axis.set_major_locator(LogLocator(base=10))
    axis.set_major_formatter(FuncFormatter(_px_ticks))
    axis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))


def histogram_bins(values: np.ndarray, n: int = 50) -> tuple[np.ndarray, float]:
    """Bin edges over ``[0, p99]`` plus one overflow bin; returns (edges, overflow start)."""
    hi = float(np.percentile(values, 99)) if values.size else 1.0
    hi = max(hi, 1e-3)
    edges = np.linspace(0.0, hi, n + 1)
    return np.append(edges, hi + hi / n), hi


def histogram_cdf_figure(errors: dict[str, pd.DataFrame], title: str) -> plt.Figure:
    """Histogram (log counts, shared bins, overflow in a labelled last bin) and empirical CDF
    (log x), one curve per variant: log counts keep a tall spike of one variant from flattening
    the others."""
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    allv = np.concatenate(
        [_finite(d)["error_px"].to_numpy() for d in errors.values()] or [np.zeros(1)]
    )
    bins, hi = histogram_bins(allv)
    drawn = False
    labels: list[str] = []
    for (label, df), c in zip(errors.items(), COLORS, strict=False):
        e = _finite(df)["error_px"].to_numpy()
        if e.size == 0:
            continue
        drawn = True
        over = int(np.count_nonzero(e > hi))
        lab = f"{label} ({over} beyond {hi:.3g} px)" if over else label
        a.hist(np.minimum(e, bins[-1] - 1e-9), bins=bins, histtype="step", color=c, label=lab)
        s = np.sort(np.maximum(e, FLOOR_PX))
        b.plot(s, np.arange(1, s.size + 1) / s.size, color=c, label=lab)
        labels.append(lab)
    if drawn:
        a.set_yscale("log")
        a.set_ylim(bottom=0.7)
        a.yaxis.set_major_formatter(FuncFormatter(_px_ticks))
    a.axvspan(hi, bins[-1], color="#eeeeee", zorder=0)
    ticks = [t for t in a.get_xticks() if 0 <= t < hi * 0.9]
    a.set_xticks([*ticks, (hi + bins[-1]) / 2], [f"{t:g}" for t in ticks] + [f">{hi:.2g}"])
    a.set_xlim(0, bins[-1])
    a.set_xlabel("endpoint error (px); last bin: everything beyond")
    a.set_ylabel("streaks (log scale)")
    a.set_title("histogram, same bins for all", fontsize=9)
    if drawn:  # one legend for both panels, under them: it hides no bar and no curve
        fig.legend(
            handles=b.get_lines(),
            labels=labels,
            loc="upper center",
            bbox_to_anchor=(0.5, 0.0),
            ncol=min(len(labels), 2),
            fontsize=8,
            frameon=False,
        )
    _log_px_axis(b.set_xscale, b.xaxis)
    b.set_xlabel(f"endpoint error (px, log; below {FLOOR_PX:g} drawn at {FLOOR_PX:g})")
    b.set_ylabel("fraction of streaks")
    b.set_title("cumulative distribution", fontsize=9)
    b.grid(alpha=0.3, which="both")
    fig.suptitle(title)
    return fig


def histogram_cdf(errors: dict[str, pd.DataFrame], title: str) -> bytes:
    """:func:`histogram_cdf_figure` as PNG bytes."""
    return _png(histogram_cdf_figure(errors, title))


def cell_medians(
    df: pd.DataFrame, width: int, height: int, nx: int = 16, ny: int = 9
) -> tuple[np.ndarray, np.ndarray]:
    """Median endpoint error and streak count per image cell ``(ny, nx)`` (start positions);
    NaN where a cell has fewer than :data:`MIN_CELL` streaks."""
    d = _finite(df)
    ix = np.clip((d["start_x"].to_numpy() / width * nx).astype(int), 0, nx - 1)
    iy = np.clip((d["start_y"].to_numpy() / height * ny).astype(int), 0, ny - 1)
    e = d["error_px"].to_numpy()
    med = np.full((ny, nx), np.nan)
    n = np.zeros((ny, nx), dtype=int)
    np.add.at(n, (iy, ix), 1)
    for j, i in zip(*np.nonzero(n >= MIN_CELL), strict=True):
        med[j, i] = float(np.median(e[(iy == j) & (ix == i)]))
    return med, n


def grid_shape(n_streaks: int, nx: int = 16, ny: int = 9, per_cell: float = 5.0) -> tuple[int, int]:
    """Cells of the position map: 16 × 9, made coarser (same aspect) until the average cell
    holds ``per_cell`` streaks, down to 2 × 1."""
    s = min(1.0, float(np.sqrt(max(n_streaks, 1) / (nx * ny * per_cell))))
    return max(2, round(nx * s)), max(1, round(ny * s))


def error_vs_position_figure(df: pd.DataFrame, width: int, height: int, title: str) -> plt.Figure:
    """Median endpoint error in image cells on a colour scale from 0 px; no numbers in the cells.

    Cells with fewer than :data:`MIN_CELL` streaks have no median and are hatched grey, cells
    with a median from fewer than :data:`FEW_CELL` streaks carry a light hatch; the streak
    counts are summarised in a note under the map.
    """
    nx, ny = grid_shape(len(_finite(df)))
    med, n = cell_medians(df, width, height, nx, ny)
    fig, ax = plt.subplots(figsize=(10, 5.6))
    ok = np.isfinite(med)
    vmax = float(np.nanmax(med)) if ok.any() else 1.0
    im = ax.imshow(
        np.ma.masked_invalid(med),
        extent=(0, width, height, 0),
        cmap="viridis",
        aspect="auto",
        vmin=0.0,
        vmax=max(vmax, 1e-9),
    )
    ax.set_facecolor("white")
    if ok.any():
        fig.colorbar(im, ax=ax, label="median endpoint error (px), scale from 0")
    else:
        ax.text(width / 2, height / 2, "too few streaks per cell", ha="center", va="center")
    cw, chh = width / nx, height / ny
    sparse = (n > 0) & ~ok
    few = ok & (n < FEW_CELL)
    for mask, hatch, face in ((sparse, "xx", "#dddddd"), (few, "//", "none")):
        for j, i in zip(*np.nonzero(mask), strict=True):
            ax.add_patch(
                Rectangle(
                    (i * cw, j * chh), cw, chh, facecolor=face, edgecolor="#888888",
                    hatch=hatch, lw=0.0, alpha=0.6,
                )
            )  # fmt: skip
    handles = [
        Patch(facecolor="#dddddd", edgecolor="#888888", hatch="xx", label=f"< {MIN_CELL} streaks"),
        Patch(facecolor="white", edgecolor="#888888", hatch="//", label=f"< {FEW_CELL} streaks"),
        Patch(facecolor="white", edgecolor="#888888", label="no streaks"),
    ]
    ax.legend(
        handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.13), ncol=3,
        frameon=False,
    )  # fmt: skip
    counts = n[ok]
    note = (
        f"streaks per coloured cell: min {counts.min()}, median {np.median(counts):g}, "
        f"max {counts.max()} ({int(counts.sum())} of {int(n.sum())} streaks)"
        if ok.any()
        else f"{int(n.sum())} streaks"
    )
    ax.text(0.0, -0.2, note, transform=ax.transAxes, ha="left", va="top", fontsize=7)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.set_title(f"{title}; median error in {nx} × {ny} cells", fontsize=10)
    return fig


def error_vs_position(df: pd.DataFrame, width: int, height: int, title: str) -> bytes:
    """:func:`error_vs_position_figure` as PNG bytes."""
    return _png(error_vs_position_figure(df, width, height, title))


def error_vs_speed(errors: dict[str, pd.DataFrame], title: str) -> bytes:
    """Endpoint error (log) against angular speed at mid-exposure, with binned medians."""
    fig, ax = plt.subplots(figsize=(10, 4.6))
    for (label, df), c in zip(errors.items(), COLORS, strict=False):
        d = _finite(df)
        if len(d) == 0:
            continue
        w, e = d["omega_radps"].to_numpy(), np.maximum(d["error_px"].to_numpy(), FLOOR_PX)
        ax.scatter(w, e, s=2, alpha=0.25, color=c, rasterized=True)
        edges = np.quantile(w, np.linspace(0, 1, 11))
        k = np.clip(np.searchsorted(edges, w, side="right") - 1, 0, 9)
        med = [np.median(e[k == i]) if np.any(k == i) else np.nan for i in range(10)]
        ax.plot((edges[:-1] + edges[1:]) / 2, med, color=c, lw=2, label=f"{label} (median)")
    ax.set_xlabel("angular speed |ω| at mid-exposure (rad/s)")
    _log_px_axis(ax.set_yscale, ax.yaxis)
    ax.set_ylabel("endpoint error (px, log)")
    ax.grid(alpha=0.3, which="major")
    ax.legend(fontsize=8)
    ax.set_title(title)
    return _png(fig)


def contiguous_runs(frames: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the runs of consecutive frame numbers in ``frames`` (sorted order)."""
    f = np.asarray(frames)
    if f.size == 0:
        return []
    order = np.argsort(f, kind="stable")
    breaks = np.nonzero(np.diff(f[order]) != 1)[0] + 1
    return list(np.split(order, breaks))


def per_frame_figure(frame_stats: pd.DataFrame, title: str) -> plt.Figure:
    """Mean endpoint error per frame, one colour per variant: markers at every frame, lines
    only between consecutive frames (never across frames that are missing, e.g. held out)."""
    fig, ax = plt.subplots(figsize=(11, 3.5))
    for (label, grp), c in zip(frame_stats.groupby("variant", sort=False), COLORS, strict=False):
        f, m = grp["frame"].to_numpy(), grp["mean_px"].to_numpy(float)
        for k, run in enumerate(contiguous_runs(f)):
            ax.plot(
                f[run], m[run], "o-", color=c, ms=3, lw=1.0,
                label=f"{label} mean" if k == 0 else None,
            )  # fmt: skip
    ax.set_xlabel("frame (frames without a point: none of their streaks used; no line across)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    _log_px_axis(ax.set_yscale, ax.yaxis)
    ax.set_ylabel("mean endpoint error (px, log)")
    ax.grid(alpha=0.3, which="major")
    if len(frame_stats):
        ax.legend(fontsize=8)
    ax.set_title(title)
    return fig


def per_frame_plot(frame_stats: pd.DataFrame, title: str) -> bytes:
    """:func:`per_frame_figure` as PNG bytes."""
    return _png(per_frame_figure(frame_stats, title))


def _stretch(img: np.ndarray) -> np.ndarray:
    """Gray image scaled to [0, 1] between its 1st and 99.9th percentiles (dots visible)."""
    g = img.mean(axis=2) if img.ndim == 3 else img.astype(float)
    lo, hi = np.percentile(g, [1.0, 99.9])
    return np.clip((g - lo) / max(hi - lo, 1e-9), 0.0, 1.0)


def overlay(
    image: np.ndarray, df: pd.DataFrame, track: Callable[[pd.DataFrame], np.ndarray], title: str
) -> bytes:
    """A frame with measured streaks (green, start marked) and predicted tracks (red dashed),
    and a zoom on the streak with the largest endpoint error.

    ``track(df) -> (N, T, 2)`` gives the predicted positions of each streak over its exposure.
    """
    img = _stretch(np.asarray(image))
    h, w = img.shape[:2]
    fig, (ax, zx) = plt.subplots(
        1, 2, figsize=(13, 13 * h / w / 1.6), gridspec_kw={"width_ratios": [1.6, 1]}
    )
    pts = track(df)
    for a in (ax, zx):
        a.imshow(img, cmap="gray", vmin=0, vmax=1)
        for (_, r), p in zip(df.iterrows(), pts, strict=True):
            a.plot([r.start_x, r.end_x], [r.start_y, r.end_y], color="#00ff00", lw=1.0)
            a.plot([r.start_x], [r.start_y], "o", color="#00ff00", ms=2)
            a.plot(p[:, 0], p[:, 1], color="#ff2020", lw=0.9, ls="--")
        a.set_axis_off()
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    if len(df):
        k = int(np.nanargmax(df["error_px"].to_numpy()))
        r = df.iloc[k]
        cx, cy = (r.start_x + r.end_x) / 2, (r.start_y + r.end_y) / 2
        half = max(12.0, 0.8 * float(np.hypot(r.end_x - r.start_x, r.end_y - r.start_y)))
        zx.set_xlim(cx - half, cx + half)
        zx.set_ylim(cy + half, cy - half)
        zx.set_title(
            f"zoom: worst streak {int(r.streak_id)}, error {r.error_px:.3f} px", fontsize=9
        )
    ax.set_title(title + "  (green: measured, red dashed: predicted)", fontsize=9)
    return _png(fig)


def model_bars_figure(summary: dict[str, dict[str, float]], title: str) -> plt.Figure:
    """Mean / median / p95 endpoint error per motion model: horizontal bars on a linear axis,
    the model names on the y axis (they never overlap) and each bar's value written beside it.
    The statistics have their own colours (:data:`STAT_COLORS`), not the variants'."""
    labels = list(summary)
    y = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(10, 0.9 + 0.75 * len(labels)))
    top = max([summary[lbl][k] for lbl in labels for k in STAT_COLORS] + [1e-9])
    for k, (key, c) in enumerate(STAT_COLORS.items()):
        vals = [summary[lbl][key] for lbl in labels]
        ys = y + (k - 1) * 0.26
        ax.barh(ys, vals, 0.26, color=c, label=key.replace("_px", ""))
        for yy, v in zip(ys, vals, strict=True):
            if np.isfinite(v):
                txt = f"{v:.3f}" if v >= 0.1 or v == 0 else f"{v:.2g}"
                ax.text(v + top * 0.01, yy, txt, va="center", fontsize=7)
    ax.set_yticks(y, labels, fontsize=9)
    ax.invert_yaxis()
    ax.set_xlim(0, top * 1.12)
    ax.set_xlabel("endpoint error (px)")
    ax.grid(alpha=0.3, axis="x")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return fig


def model_bars(summary: dict[str, dict[str, float]], title: str) -> bytes:
    """:func:`model_bars_figure` as PNG bytes."""
    return _png(model_bars_figure(summary, title))
