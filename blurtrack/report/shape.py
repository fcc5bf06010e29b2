"""Shape consistency of the detected streaks, for the report.

Within one frame every dot draws nearly the same curve, so detection measures how far each
streak's start-to-end vector lies from its frame's consensus (``shape_deviation_px``,
:mod:`blurtrack.detect.separation.quality`). Its distribution per frame says how well detection did
(merged chains, fragments and hooks lie far out) and, for the streaks kept, how consistent
the measured shapes are. :func:`shape_summary` condenses the table's column (None when the
table has none); :func:`shape_section` renders it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

#: Percentiles of the deviation reported (overall and per frame).
PERCENTILES = (50, 90, 99)


def _dist(dev: np.ndarray) -> dict[str, Any]:
    dev = dev[np.isfinite(dev)]
    out: dict[str, Any] = {"n": int(dev.size)}
    for q in PERCENTILES:
        out[f"p{q}_px"] = float(np.percentile(dev, q)) if dev.size else None
    return out


def shape_summary(table: pd.DataFrame) -> dict[str, Any] | None:
    """Distribution of ``shape_deviation_px`` over the table and per frame (None without the
    column or without any finite value)."""
    if "shape_deviation_px" not in table.columns or len(table) == 0:
        return None
    dev = table["shape_deviation_px"].to_numpy(float)
    if not np.isfinite(dev).any():
        return None
    ok = table["quality_ok"].to_numpy(bool) if "quality_ok" in table.columns else None
    overall = _dist(dev)
    overall["n_streaks"] = len(table)
    if ok is not None:
        overall["quality_ok"] = int(ok.sum())
        overall["kept"] = _dist(dev[ok])
    for col in ("source", "reason"):  # detection tables of version 2 and later
        if col in table.columns:
            counts = table[col].astype(str).value_counts()
            overall[col] = {str(k): int(v) for k, v in counts.items()}
    frames = []
    for f, d in table.groupby("frame", sort=True):
        row = {
            "frame": int(f),
            "n_streaks": len(d),
            **_dist(d["shape_deviation_px"].to_numpy(float)),
        }
        if ok is not None:
            row["quality_ok"] = int(d["quality_ok"].to_numpy(bool).sum())
        frames.append(row)
    return {"overall": overall, "per_frame": frames}


def _px(v: Any) -> str:
    return "–" if v is None else f"{float(v):.2f}"


def shape_section(shape: dict[str, Any] | None) -> list[str]:
    """HTML parts of the shape-consistency section (none for None)."""
    if not shape:
        return []
    o = shape["overall"]
    qs = [f"p{q}_px" for q in PERCENTILES]
    head = "".join(f"<th>{q}th pct (px)</th>" for q in PERCENTILES)
    kept = o.get("kept")
    rows = [
        f"<tr><td>all measured</td><td>{o['n']}</td>"
        + "".join(f"<td>{_px(o[k])}</td>" for k in qs)
        + "</tr>"
    ]
    if kept:
        rows.append(
            f"<tr><td>quality_ok</td><td>{kept['n']}</td>"
            + "".join(f"<td>{_px(kept[k])}</td>" for k in qs)
            + "</tr>"
        )
    parts = [
        "<h2>Shape consistency (detection)</h2>",
        "<p>Distance of each streak's start-to-end vector from its frame's consensus "
        "(<code>shape_deviation_px</code>): every dot of a frame draws nearly the same curve, "
        f"so large values are chains, fragments or hooks. {o['n']} of {o['n_streaks']} "
        "streaks had a consensus to compare with"
        + (f"; {o['quality_ok']} are <code>quality_ok</code>." if "quality_ok" in o else ".")
        + "</p>",
        f"<table><tr><th>streaks</th><th>n</th>{head}</tr>{''.join(rows)}</table>",
    ]
    for col, what in (("source", "Source"), ("reason", "Reason")):
        if col in o:
            line = ", ".join(f"{k} {v}" for k, v in sorted(o[col].items()))
            parts.append(f"<p>{what} (<code>{col}</code>): {line}.</p>")
    body = "".join(
        f"<tr><td>{int(r['frame'])}</td><td>{int(r['n_streaks'])}</td><td>{r['n']}</td>"
        + "".join(f"<td>{_px(r[k])}</td>" for k in qs)
        + (f"<td>{r['quality_ok']}</td>" if "quality_ok" in r else "")
        + "</tr>"
        for r in shape["per_frame"]
    )
    extra = (
        "<th>quality_ok</th>"
        if shape["per_frame"] and "quality_ok" in shape["per_frame"][0]
        else ""
    )
    parts.append(
        f"<details><summary><b>Per-frame shape deviation</b> ({len(shape['per_frame'])} "
        f"frames)</summary><table><tr><th>frame</th><th>streaks</th><th>n</th>{head}{extra}"
        f"</tr>{body}</table></details>"
    )
    return parts
