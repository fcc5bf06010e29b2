"""Pictures of detected streaks drawn over their frame (for the demo and for inspection).

:func:`draw_streaks` paints them into the (upscaled) frame itself with OpenCV (the benchmark's
pictures); :func:`streak_figure` makes the explained picture of ``detect --overlay`` with
matplotlib: a title, a legend of the colours and a zoomed inset; :func:`source_picture`
colours each detection by its ``source`` (point light, extended source, undetermined) and rings
the ``quality_ok`` ones' ends (``detect`` on photographs, the real-photograph benchmark).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

#: BGR colours: centre line, start, end, flagged streaks' centre line.
LINE = (60, 220, 60)
START = (40, 40, 255)
END = (255, 160, 40)
FLAGGED = (0, 200, 255)


#: BGR centre-line colours of :func:`source_picture`, by ``source``.
SOURCE_COLOURS = {"point": (80, 220, 80), "extended": (220, 80, 220), "undetermined": (0, 165, 255)}


def _bgr8(image: np.ndarray) -> np.ndarray:
    """The frame as 8-bit BGR (16-bit: its top byte; gray and BGRA converted)."""
    img = image
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.asarray(img)


def source_picture(image: np.ndarray, rows: pd.DataFrame, scale: float = 1.0) -> np.ndarray:
    """The frame dimmed and scaled by ``scale``, each detection of ``rows`` (streak-table
    rows of one frame, with ``source`` and ``quality_ok``) drawn as its centre line in its
    :data:`SOURCE_COLOURS` colour, the ``quality_ok`` ones' ends ringed in white, and a legend
    with the counts. Returns ``(round(H * scale), round(W * scale), 3)`` uint8 BGR."""
    if not scale > 0:
        raise ValueError(f"source_picture: scale must be positive, got {scale}")
    pic = cv2.resize((0.6 * _bgr8(image)).astype(np.uint8), None, fx=scale, fy=scale)
    for _, r in rows.iterrows():
        pts = np.round(np.asarray(list(r["centerline"]), float) * scale).astype(np.int32)
        colour = SOURCE_COLOURS.get(str(r["source"]), SOURCE_COLOURS["undetermined"])
        cv2.polylines(pic, [pts.reshape(-1, 1, 2)], False, colour, 2)
        if r["quality_ok"]:
            for x, y in (pts[0], pts[-1]):
                cv2.circle(pic, (int(x), int(y)), 5, (255, 255, 255), 1)
    counts = rows["source"].value_counts()
    legend = [(f"{s}: {int(counts.get(s, 0))}", c) for s, c in SOURCE_COLOURS.items()]
    legend.append((f"quality_ok (white rings): {int(rows['quality_ok'].sum())}", (255, 255, 255)))
    cv2.rectangle(pic, (4, 4), (300, 12 + 20 * len(legend)), (0, 0, 0), -1)
    for k, (text, colour) in enumerate(legend):
        cv2.putText(pic, text, (10, 22 + 20 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1)
    return pic


def write_source_picture(
    path: str | Path, image: np.ndarray, rows: pd.DataFrame, scale: float = 1.0
) -> Path:
    """Draw :func:`source_picture` and write it atomically to ``path``, encoded by its
    suffix as :func:`blurtrack.io.images.write_image` does (``.png``, ``.jpg``, ``.tif``)."""
    from blurtrack.io.images import write_image

    return write_image(path, source_picture(image, rows, scale))


def draw_streaks(image: np.ndarray, rows: pd.DataFrame, scale: int = 2) -> np.ndarray:
    """Draw the streaks of ``rows`` (streak-table rows of one frame) over ``image``.

    The frame is converted to 8-bit BGR and upscaled by ``scale`` so that sub-pixel lines stay
    visible. Centre lines in green (orange when flagged), start of exposure as a red dot, end
    as a blue one. Returns the picture ``(H * scale, W * scale, 3)`` uint8.
    """
    img = cv2.resize(_bgr8(image), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = (img.astype(np.float32) * 0.7).astype(np.uint8)  # dim, so the drawing stands out
    shift = 4  # fixed-point bits: sub-pixel drawing
    f = float(scale * (1 << shift))

    def fix(xy: ArrayLike) -> np.ndarray:
        # pixel centres are at integer coordinates; the upscaled pixel i spans [i s, (i+1) s)
        return np.rint((np.asarray(xy, float) + 0.5) * f - 0.5 * (1 << shift)).astype(np.int32)

    flag_cols = [c for c in ("clipped", "saturated", "merged", "faint") if c in rows]
    for _, r in rows.iterrows():
        pts = np.asarray(r["centerline"], dtype=float).reshape(-1, 2)
        flagged = bool(any(r[c] for c in flag_cols))
        if len(pts) >= 2:
            cv2.polylines(
                img,
                [fix(pts).reshape(-1, 1, 2)],
                False,
                FLAGGED if flagged else LINE,
                1,
                cv2.LINE_AA,
                shift,
            )
        cv2.circle(
            img, tuple(fix([r["start_x"], r["start_y"]])), 3 << shift, START, -1, cv2.LINE_AA, shift
        )
        cv2.circle(
            img, tuple(fix([r["end_x"], r["end_y"]])), 3 << shift, END, -1, cv2.LINE_AA, shift
        )
    return img


#: Matplotlib colours of :func:`streak_figure` (RGB twins of the BGR constants above).
OK_COLOR = "#3cdc3c"
FLAGGED_COLOR = "#ffa000"
START_COLOR = "#ff2828"
END_COLOR = "#28a0ff"


def flagged_mask(rows: pd.DataFrame) -> np.ndarray:
    """``(N,)`` True for streaks that are not ``quality_ok`` (or, in a table without that
    column, that carry any of the ``clipped``, ``saturated``, ``merged``, ``faint`` flags)."""
    if "quality_ok" in rows:
        return ~rows["quality_ok"].to_numpy(bool)
    cols = [c for c in ("clipped", "saturated", "merged", "faint") if c in rows]
    if not cols:
        return np.zeros(len(rows), bool)
    return np.asarray(rows[cols].to_numpy(bool).any(axis=1))


def _gray(image: np.ndarray) -> np.ndarray:
    """The frame as gray float in [0, 1], stretched between its 1st and 99.9th percentiles so
    that a dark laser-grid frame shows its streaks."""
    g = np.asarray(image, dtype=np.float64)
    if g.ndim == 3:
        g = g[..., :3].mean(axis=2)
    lo, hi = np.percentile(g, [1.0, 99.9])
    return np.clip((g - lo) / max(float(hi - lo), 1e-9), 0.0, 1.0)


def densest_window(
    mid: np.ndarray,
    size: tuple[float, float],
    shape: tuple[int, int],
    weight: np.ndarray | None = None,
) -> tuple[float, float]:
    """The ``(x0, y0)`` of the window of ``size = (w, h)`` px inside an image of ``shape = (H, W)``
    whose streak mid-points ``mid (N, 2)`` weigh most (``weight (N,)``, default 1 each),
    scanned on a grid of quarter windows."""
    wt = np.ones(len(mid)) if weight is None else np.asarray(weight, float)
    w, h = size
    big_h, big_w = shape
    xs = np.linspace(0.0, max(big_w - w, 0.0), max(2, int(4 * big_w / max(w, 1.0)) + 1))
    ys = np.linspace(0.0, max(big_h - h, 0.0), max(2, int(4 * big_h / max(h, 1.0)) + 1))
    best, where = -1.0, (0.0, 0.0)
    for y0 in ys:
        for x0 in xs:
            inside = (
                (mid[:, 0] >= x0) & (mid[:, 0] < x0 + w) & (mid[:, 1] >= y0) & (mid[:, 1] < y0 + h)
            )
            score = float(wt[inside].sum())
            if score > best:
                best, where = score, (float(x0), float(y0))
    return where


def _points(centerline: Any) -> np.ndarray:
    """A centre line as ``(N, 2)`` floats, from an ``(N, 2)`` array, a flat list or the object
    array of points that Parquet gives back."""
    return np.asarray([np.asarray(p, float).ravel() for p in centerline], float).reshape(-1, 2)


def _draw(ax: Any, rows: pd.DataFrame, flagged: np.ndarray, lw: float, ms: float) -> None:
    from matplotlib.collections import LineCollection

    for bad, color in ((False, OK_COLOR), (True, FLAGGED_COLOR)):
        sel = rows[flagged == bad]
        lines = [_points(c) for c in sel["centerline"]]
        lines = [p for p in lines if len(p) >= 2]
        if lines:
            ax.add_collection(LineCollection(lines, colors=color, linewidths=lw))
    ax.plot(rows["start_x"], rows["start_y"], "o", color=START_COLOR, ms=ms, mew=0)
    ax.plot(rows["end_x"], rows["end_y"], "o", color=END_COLOR, ms=ms, mew=0)


def streak_figure(
    image: np.ndarray,
    rows: pd.DataFrame,
    frame: int | None = None,
    width_px: int = 1600,
    zoom: float = 2.0,
) -> Any:
    """A titled matplotlib figure of the streaks ``rows`` (streak-table rows of one frame) over
    ``image``: the frame scaled to ``width_px`` pixels wide (at 100 dpi), contrast-stretched;
    centre lines green (``quality_ok``) or orange (flagged), start of exposure red, end blue; a
    legend of these colours; and an inset showing the region with the most streaks (flagged ones
    weighing more) at ``zoom`` picture pixels per frame pixel, its outline drawn on the frame.
    The title states the frame, the number of streaks and how many are ``quality_ok``. Returns
    the :class:`matplotlib.figure.Figure` (no pyplot state: save it with ``fig.savefig``).
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    g = _gray(image)
    h, w = g.shape
    flagged = flagged_mask(rows)
    n, n_ok = len(rows), int(np.count_nonzero(~flagged))
    dpi = 100.0
    title_in = 0.55
    fig_w = width_px / dpi
    img_h_in = fig_w * h / w
    fig = Figure(figsize=(fig_w, img_h_in + title_in), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, img_h_in / (img_h_in + title_in)))
    ax.imshow(g, cmap="gray", vmin=0.0, vmax=1.0, interpolation="antialiased")
    _draw(ax, rows, flagged, lw=1.0, ms=2.0)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    what = f"frame {frame}: " if frame is not None else ""
    fig.suptitle(
        f"{what}{n} streaks detected, {n_ok} quality_ok, {n - n_ok} flagged "
        f"({w} × {h} px frame shown at {width_px} px wide)",
        y=1.0 - 0.08 * title_in / (img_h_in + title_in),
        va="top",
        fontsize=13,
    )

    # the inset: a third of the picture's width, the frame at `zoom` x its own resolution
    frac = 0.34
    win_w = frac * width_px / zoom  # frame pixels: each drawn as zoom x zoom picture pixels
    win_h = min(win_w * 0.75, float(h))
    win_w = min(win_w, float(w))
    mid = (
        np.column_stack(
            [(rows["start_x"] + rows["end_x"]) / 2, (rows["start_y"] + rows["end_y"]) / 2]
        )
        if n
        else np.empty((0, 2))
    )
    # the most streaks, a flagged one counting as three (so that the zoom shows one if it can)
    x0, y0 = densest_window(mid, (win_w, win_h), (h, w), 1.0 + 2.0 * flagged)
    in_h = frac * (win_h / win_w) * w / h  # inset height as a fraction of the axes
    corners = {
        "upper right": (1.0 - frac - 0.01, 1.0 - in_h - 0.01),
        "lower right": (1.0 - frac - 0.01, 0.01),
        "upper left": (0.01, 1.0 - in_h - 0.01),
        "lower left": (0.01, 0.01),
    }

    def cost(name: str) -> tuple[int, int]:
        cx, cy = corners[name]
        ax0, ax1 = cx * w, (cx + frac) * w
        ay0, ay1 = (1.0 - cy - in_h) * h, (1.0 - cy) * h
        hidden = int(
            np.count_nonzero(
                (mid[:, 0] >= ax0) & (mid[:, 0] < ax1) & (mid[:, 1] >= ay0) & (mid[:, 1] < ay1)
            )
        )
        overlaps = not (x0 + win_w < ax0 or x0 > ax1 or y0 + win_h < ay0 or y0 > ay1)
        return (int(overlaps), hidden)

    corner = min(corners, key=cost)
    cx, cy = corners[corner]
    inset = ax.inset_axes((cx, cy, frac, in_h))
    inset.imshow(g, cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest")
    _draw(inset, rows, flagged, lw=1.6, ms=4.0)
    inset.set_xlim(x0 - 0.5, x0 + win_w - 0.5)
    inset.set_ylim(y0 + win_h - 0.5, y0 - 0.5)
    inset.set_xticks([])
    inset.set_yticks([])
    for s in inset.spines.values():
        s.set_edgecolor("white")
        s.set_linewidth(1.5)
    ax.indicate_inset_zoom(inset, edgecolor="white", alpha=0.9, linewidth=1.2)
    where = f"x {x0:.0f}–{x0 + win_w:.0f}, y {y0:.0f}–{y0 + win_h:.0f} px"
    inset.text(
        0.0, 1.0, f"zoom, 1 frame px = {zoom:g} px: {where}",
        transform=inset.transAxes, ha="left", va="bottom", fontsize=9, color="white",
        bbox={"facecolor": "black", "alpha": 0.6, "edgecolor": "none", "pad": 2},
    )  # fmt: skip

    handles = [
        Line2D([], [], color=OK_COLOR, lw=2, label=f"centre line, quality_ok ({n_ok})"),
        Line2D([], [], color=FLAGGED_COLOR, lw=2, label=f"centre line, flagged ({n - n_ok})"),
        Line2D([], [], ls="", marker="o", color=START_COLOR, label="start of exposure"),
        Line2D([], [], ls="", marker="o", color=END_COLOR, label="end of exposure"),
    ]
    # the legend in another corner, preferably on the inset's side, off the zoomed region
    # (its box taken as a quarter of the width by a fifth of the height)
    order: list[Literal["upper right", "lower right", "upper left", "lower left"]] = [
        "lower right", "upper right", "lower left", "upper left",
    ]  # fmt: skip
    side = corner.split()[1]
    order.sort(key=lambda c: c.split()[1] != side)

    def covers_zoom(c: str) -> bool:
        lx0 = 0.0 if c.endswith("left") else 0.75 * w
        ly0 = 0.0 if c.startswith("upper") else 0.8 * h
        return not (
            x0 + win_w < lx0 or x0 > lx0 + 0.25 * w or y0 + win_h < ly0 or y0 > ly0 + 0.2 * h
        )

    free = [c for c in order if c != corner and not covers_zoom(c)]
    loc = free[0] if free else next(c for c in order if c != corner)
    ax.legend(handles=handles, loc=loc, fontsize=10, framealpha=1.0)
    return fig


def figure_pixels(fig: Any) -> np.ndarray:
    """The figure drawn at its own dpi as an 8-bit BGR image ``(H, W, 3)``."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    img = cv2.imdecode(np.frombuffer(buf.getvalue(), np.uint8), cv2.IMREAD_COLOR)
    return np.asarray(img)


def write_streak_picture(
    path: str | Path, image: np.ndarray, rows: pd.DataFrame, frame: int | None = None
) -> Path:
    """Draw :func:`streak_figure` and write it atomically to ``path``, encoded by its suffix as
    :func:`blurtrack.io.images.write_image` does (``.png``, ``.jpg``, ``.tif``)."""
    from blurtrack.io.images import write_image

    return write_image(path, figure_pixels(streak_figure(image, rows, frame)))
