"""The self-contained HTML page of a report (figures embedded as base64 PNG)."""

from __future__ import annotations

import base64
import html
from typing import Any

import pandas as pd

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;
text-align:right}th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}
.warn{background:#fff4e0;border-left:4px solid #f0a020;padding:0.4em 0.8em;margin:0.3em 0}
img{max-width:100%;border:1px solid #ddd;margin:0.3em 0 1.2em}
"""


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.4g}"
    return html.escape(str(v))


def _table(rows: dict[str, dict[str, Any]], cols: list[str], first: str) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in [first, *cols])
    body = "".join(
        "<tr>"
        + f"<td>{html.escape(k)}</td>"
        + "".join(f"<td>{_fmt(r.get(c))}</td>" for c in cols)
        + "</tr>"
        for k, r in rows.items()
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def render(
    summary: dict[str, Any], figs: list[tuple[str, bytes]], frame_stats: pd.DataFrame
) -> str:
    """HTML text of the report."""
    cols = ["n", "mean_px", "median_px", "p95_px", "rms_px"]
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>BlurTrack endpoint-error "
        f"report</title><style>{_STYLE}</style></head><body>",
        "<h1>BlurTrack endpoint-error report</h1>",
        f"<p>{summary['n_streaks']} streaks in {summary['n_frames']} frames. Endpoint error: "
        "distance between the measured end of a streak and the end predicted by the "
        "gyro-driven blur model from its measured start.</p>",
    ]
    for w in summary.get("warnings", []):
        parts.append(f"<div class='warn'>{html.escape(str(w))}</div>")
    parts.append("<h2>Before and after calibration</h2>")
    parts.append(_table(summary["overall"], cols, "calibration"))
    labels = summary.get("motion_model_labels", {})
    parts.append("<h2>Motion models (after calibration)</h2>")
    parts.append(
        _table({labels.get(k, k): v for k, v in summary["motion_models"].items()}, cols, "model")
    )
    fit = summary.get("fit") or {}
    if fit.get("values"):
        parts.append(
            f"<h2>Fit</h2><p>status: <b>{html.escape(str(fit.get('status')))}</b>, "
            f"iterations {fit.get('iterations')}, outliers {fit.get('n_outliers')}, "
            f"wrongly oriented {fit.get('n_flipped')}</p>"
        )
        tr = fit.get("tracks_inliers")
        kind = html.escape(str(fit.get("residuals", "endpoints")))
        extra = ""
        if isinstance(tr, dict):
            extra = (
                f"; {fit.get('n_tracks')} inter-frame tracks of streak midpoints "
                f"({fit.get('n_track_outliers')} outliers), error mean "
                f"{_fmt(tr.get('mean_px'))} px, p95 {_fmt(tr.get('p95_px'))} px"
            )
        parts.append(f"<p>fitted residuals: <b>{kind}</b>{extra}</p>")
        rows = {
            k: {
                "value": v,
                "sigma": (fit.get("sigma") or {}).get(k),
                "truth": (fit.get("truth") or {}).get(k),
            }
            for k, v in fit["values"].items()
        }
        parts.append(_table(rows, ["value", "sigma", "truth"], "parameter"))
        for key in ("holdout_inliers", "holdout_all", "train_inliers"):
            if fit.get(key):
                parts.append(
                    f"<p>{key.replace('_', ' ')}: "
                    + ", ".join(f"{k} {_fmt(v)}" for k, v in fit[key].items())
                    + "</p>"
                )
    for title, png in figs:
        b64 = base64.b64encode(png).decode("ascii")
        parts.append(
            f"<h3>{html.escape(title)}</h3><img alt='{html.escape(title)}' "
            f"src='data:image/png;base64,{b64}'>"
        )
    ba = frame_stats[frame_stats["variant"].isin(["before", "after"])]
    if len(ba):
        piv = ba.pivot_table(index="frame", columns="variant", values="mean_px")
        rows = {str(int(f)): {c: float(piv.loc[f, c]) for c in piv.columns} for f in piv.index}
        parts.append("<h2>Per-frame mean endpoint error (px)</h2>")
        parts.append(_table(rows, list(piv.columns), "frame"))
    parts.append("</body></html>")
    return "\n".join(parts)
