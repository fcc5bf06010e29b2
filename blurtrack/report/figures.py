"""Report figures (matplotlib, Agg backend) returned as PNG bytes."""

from __future__ import annotations

import io
from collections.abc import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

COLORS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e")


def _png(fig: plt.Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _finite(df: pd.DataFrame) -> pd.DataFrame:
    return df[np.isfinite(df["error_px"].to_numpy())]


def histogram_cdf(errors: dict[str, pd.DataFrame], title: str) -> bytes:
    """Histogram and empirical CDF of endpoint errors, one curve per label."""
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    allv = np.concatenate(
        [_finite(d)["error_px"].to_numpy() for d in errors.values()] or [np.zeros(1)]
    )
    hi = float(np.percentile(allv, 99)) if allv.size else 1.0
    bins = np.linspace(0, max(hi, 1e-3), 60)
    for (label, df), c in zip(errors.items(), COLORS, strict=False):
        e = _finite(df)["error_px"].to_numpy()
        if e.size == 0:
            continue
        a.hist(np.clip(e, 0, bins[-1]), bins=bins, histtype="step", color=c, label=label)
        s = np.sort(e)
        b.plot(s, np.arange(1, s.size + 1) / s.size, color=c, label=label)
    a.set_xlabel("endpoint error (px)")
    a.set_ylabel("streaks")
    a.legend(fontsize=8)
    b.set_xscale("symlog", linthresh=0.1)
    b.set_xlabel("endpoint error (px)")
    b.set_ylabel("fraction of streaks")
    b.grid(alpha=0.3)
    fig.suptitle(title)
    return _png(fig)


def error_vs_position(df: pd.DataFrame, width: int, height: int, title: str) -> bytes:
    """Mean endpoint error in image cells (16 × 9 grid) at the streaks' start positions."""
    d = _finite(df)
    nx, ny = 16, 9
    ix = np.clip((d["start_x"].to_numpy() / width * nx).astype(int), 0, nx - 1)
    iy = np.clip((d["start_y"].to_numpy() / height * ny).astype(int), 0, ny - 1)
    s = np.zeros((ny, nx))
    n = np.zeros((ny, nx))
    np.add.at(s, (iy, ix), d["error_px"].to_numpy())
    np.add.at(n, (iy, ix), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.where(n > 0, s / n, np.nan)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    im = ax.imshow(m, extent=(0, width, height, 0), cmap="viridis", aspect="auto")
    fig.colorbar(im, ax=ax, label="mean endpoint error (px)")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.set_title(title)
    return _png(fig)


def error_vs_speed(errors: dict[str, pd.DataFrame], title: str) -> bytes:
    """Endpoint error against angular speed at mid-exposure, with binned medians."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for (label, df), c in zip(errors.items(), COLORS, strict=False):
        d = _finite(df)
        if len(d) == 0:
            continue
        w, e = d["omega_radps"].to_numpy(), d["error_px"].to_numpy()
        ax.scatter(w, e, s=2, alpha=0.25, color=c)
        edges = np.quantile(w, np.linspace(0, 1, 11))
        k = np.clip(np.searchsorted(edges, w, side="right") - 1, 0, 9)
        med = [np.median(e[k == i]) if np.any(k == i) else np.nan for i in range(10)]
        ax.plot((edges[:-1] + edges[1:]) / 2, med, color=c, lw=2, label=f"{label} (median)")
    ax.set_xlabel("angular speed |ω| (rad/s)")
    ax.set_ylabel("endpoint error (px)")
    ax.set_yscale("symlog", linthresh=0.1)
    ax.legend(fontsize=8)
    ax.set_title(title)
    return _png(fig)


def per_frame_plot(frame_stats: pd.DataFrame, title: str) -> bytes:
    fig, ax = plt.subplots(figsize=(11, 3.5))
    for (label, grp), c in zip(frame_stats.groupby("variant", sort=False), COLORS, strict=False):
        ax.plot(grp["frame"], grp["mean_px"], ".-", color=c, label=f"{label} mean", ms=3)
    ax.set_xlabel("frame")
    ax.set_ylabel("mean endpoint error (px)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title(title)
    return _png(fig)


def _stretch(img: np.ndarray) -> np.ndarray:
    """Gray image scaled to [0, 1] between its 1st and 99.9th percentiles (dots visible)."""
    g = img.mean(axis=2) if img.ndim == 3 else img.astype(float)
    lo, hi = np.percentile(g, [1.0, 99.9])
    return np.clip((g - lo) / max(hi - lo, 1e-9), 0.0, 1.0)


def overlay(
    image: np.ndarray, df: pd.DataFrame, track: Callable[[pd.DataFrame], np.ndarray], title: str
) -> bytes:
    """A frame with measured streaks (green, start marked) and predicted tracks (red dashed),
    and a zoom on the longest streak.

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
        k = int(np.argmax(np.hypot(df["end_x"] - df["start_x"], df["end_y"] - df["start_y"])))
        r = df.iloc[k]
        cx, cy = (r.start_x + r.end_x) / 2, (r.start_y + r.end_y) / 2
        half = max(12.0, 0.8 * float(np.hypot(r.end_x - r.start_x, r.end_y - r.start_y)))
        zx.set_xlim(cx - half, cx + half)
        zx.set_ylim(cy + half, cy - half)
        zx.set_title(f"zoom: streak {int(r.streak_id)}, error {r.error_px:.3f} px", fontsize=9)
    ax.set_title(title + "  (green: measured, red dashed: predicted)", fontsize=9)
    return _png(fig)


def model_bars(summary: dict[str, dict[str, float]], title: str) -> bytes:
    """Mean / median / p95 endpoint error per motion model."""
    labels = list(summary)
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(8, 3.8))
    for k, (key, c) in enumerate(zip(("mean_px", "median_px", "p95_px"), COLORS, strict=False)):
        ax.bar(
            x + (k - 1) * 0.27,
            [summary[lbl][key] for lbl in labels],
            0.27,
            color=c,
            label=key.replace("_px", ""),
        )
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("endpoint error (px)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title(title)
    return _png(fig)
