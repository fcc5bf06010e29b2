"""The self-contained HTML page of a report (figures embedded as base64 PNG).

No script, no external resource: the page opens offline and makes no network request.
Figures are drawn at 2× (:data:`blurtrack.report.figures.DPI`) and shown at half their pixel
width. Numbers carry their unit in the column header; fitted values are written to the
precision their 1-sigma supports (three significant digits of sigma).
"""

from __future__ import annotations

import base64
import html
import math
import struct
from typing import Any

import pandas as pd

from blurtrack.report.shape import shape_section

REPORT_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;padding:0 1em;color:#222}
.tw{overflow-x:auto}
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;
text-align:right;font-variant-numeric:tabular-nums}th{background:#f2f2f2}
td:first-child,th:first-child{text-align:left}
td.bad{background:#ffe0e0}
.warn{background:#fff4e0;border-left:4px solid #f0a020;padding:0.4em 0.8em;margin:0.3em 0}
.note{color:#555;font-size:0.92em}
img{max-width:100%;height:auto;border:1px solid #ddd;margin:0.3em 0 1.2em}
"""

#: Display scale, unit and description of each fitted parameter (calib's ``THETA_NAMES``).
PARAM_UNITS: dict[str, tuple[float, str]] = {
    "timeshift_s": (1e3, "ms"),
    "readout_s": (1e3, "ms"),
    "fx": (1.0, "px"),
    "fy": (1.0, "px"),
    "cx": (1.0, "px"),
    "cy": (1.0, "px"),
    **{f"bias_{a}": (1e3, "mrad/s") for a in "xyz"},
    **{f"rot_{a}": (180.0 / math.pi, "deg") for a in "xyz"},
    **{f"scale_{a}": (1e3, "×10⁻³") for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
}

#: Names shown for parameters whose key carries a unit the table converts.
PARAM_LABELS = {"timeshift_s": "time shift (cam→imu)", "readout_s": "readout"}

_STAT_COLS = [
    ("n", "n"),
    ("mean_px", "mean (px)"),
    ("median_px", "median (px)"),
    ("p95_px", "p95 (px)"),
    ("rms_px", "rms (px)"),
]


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def fmt_px(v: Any) -> str:
    """An error in pixels: three decimals, three significant digits below 0.1 px."""
    f = _num(v)
    if f is None:
        return "–" if v is None or isinstance(v, float) else html.escape(str(v))
    if isinstance(v, int):
        return str(v)
    return f"{f:.3f}" if abs(f) >= 0.1 or f == 0 else f"{f:.3g}"


def decimals_for(sigma: float | None) -> int | None:
    """Decimal places that show three significant digits of ``sigma`` (None: unknown)."""
    if sigma is None or sigma <= 0:
        return None
    return int(min(9, max(0, 2 - math.floor(math.log10(sigma)))))


def fmt_fixed(v: float | None, dec: int | None) -> str:
    if v is None:
        return "–"
    return f"{v:.{dec}f}" if dec is not None else f"{v:.6g}"


def html_table(head: list[str], rows: list[list[str]]) -> str:
    """Cells are already escaped HTML (``<td>`` content, or a whole ``<td ...>`` cell)."""
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join(
        "<tr>" + "".join(c if c.startswith("<td") else f"<td>{c}</td>" for c in r) + "</tr>"
        for r in rows
    )
    return f"<div class='tw'><table><tr>{h}</tr>{body}</table></div>"


def stats_table(rows: dict[str, dict[str, Any]], first: str) -> str:
    cols = [c for c, _ in _STAT_COLS]
    extra = [("max_px", "max (px)")] if any("max_px" in r for r in rows.values()) else []
    head = [first] + [h for _, h in _STAT_COLS + extra]
    body = [
        [html.escape(k)] + [fmt_px(r.get(c)) for c in cols + [c for c, _ in extra]]
        for k, r in rows.items()
    ]
    return html_table(head, body)


def fit_table(fit: dict[str, Any]) -> str:
    """Parameter, unit, value, 1-sigma, and where the truth is known: truth, error, z."""
    sig = fit.get("sigma") or {}
    truth = fit.get("truth") or {}
    has_truth = any(k in truth for k in fit["values"])
    head = ["parameter", "unit", "value", "sigma"]
    if has_truth:
        head += ["truth", "error", "z = error / sigma"]
    rows = []
    for k, v in fit["values"].items():
        scale, unit = PARAM_UNITS.get(k, (1.0, ""))
        val, s, t = _num(v), _num(sig.get(k)), _num(truth.get(k))
        val = None if val is None else val * scale
        s = None if s is None else s * scale
        t = None if t is None else t * scale
        dec = decimals_for(s)
        name = PARAM_LABELS.get(k, k)
        row = [html.escape(name), html.escape(unit), fmt_fixed(val, dec), fmt_fixed(s, dec)]
        if has_truth:
            err = None if val is None or t is None else val - t
            z = None if err is None or not s else err / s
            zc = "–" if z is None else f"{z:+.2f}"
            row += [
                fmt_fixed(t, dec),
                fmt_fixed(err, dec),
                f"<td class='bad'>{zc}</td>" if z is not None and abs(z) > 3 else zc,
            ]
        rows.append(row)
    return html_table(head, rows)


def png_size(png: bytes) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG's IHDR chunk, or None if it is not a PNG."""
    if len(png) >= 24 and png[:8] == b"\x89PNG\r\n\x1a\n" and png[12:16] == b"IHDR":
        w, h = struct.unpack(">II", png[16:24])
        return int(w), int(h)
    return None


def html_figure(title: str, png: bytes) -> str:
    b64 = base64.b64encode(png).decode("ascii")
    size = png_size(png)
    dims = f" width='{size[0] // 2}' height='{size[1] // 2}'" if size else ""
    t = html.escape(title)
    return f"<h3>{t}</h3><img alt='{t}'{dims} src='data:image/png;base64,{b64}'>"


def fit_section_html(fit: dict[str, Any]) -> list[str]:
    parts = [
        f"<h2>Fit</h2><p>status: <b>{html.escape(str(fit.get('status')))}</b>, "
        f"iterations {html.escape(str(fit.get('iterations')))}, outliers "
        f"{html.escape(str(fit.get('n_outliers')))}, wrongly oriented "
        f"{html.escape(str(fit.get('n_flipped')))}</p>"
    ]
    tr = fit.get("tracks_inliers")
    kind = html.escape(str(fit.get("residuals", "endpoints")))
    extra = ""
    if isinstance(tr, dict):
        extra = (
            f"; {html.escape(str(fit.get('n_tracks')))} inter-frame tracks of streak midpoints "
            f"({html.escape(str(fit.get('n_track_outliers')))} outliers), error mean "
            f"{fmt_px(tr.get('mean_px'))} px, p95 {fmt_px(tr.get('p95_px'))} px"
        )
    parts.append(f"<p>fitted residuals: <b>{kind}</b>{extra}</p>")
    parts.append(fit_table(fit))
    if fit.get("truth"):
        parts.append(
            "<p class='note'>truth: the simulator's true value (truth.yaml); error = value − "
            "truth; z beyond ±3 is marked.</p>"
        )
    held = {
        key.replace("_", " "): fit[key]
        for key in ("train_inliers", "holdout_inliers", "holdout_all")
        if isinstance(fit.get(key), dict)
    }
    if held:
        parts.append("<h3>Endpoint errors of the fit (its own streak selection)</h3>")
        parts.append(stats_table(held, "streaks"))
    return parts


def _flag_section(flags: dict[str, Any], n_streaks: int) -> list[str]:
    n = int(flags.get("n_flagged") or 0)
    names = ", ".join(flags.get("excluded_flags", []))
    parts = [
        "<h2>Flagged streaks (left out)</h2>",
        f"<p>{n} of {n_streaks} streaks carry a detector flag ({html.escape(names)}): the "
        "streaks calibration leaves out. They are in <code>streak_errors.csv</code> (column "
        "<code>flagged</code>) but in no other table or figure of this report.</p>",
    ]
    if n:
        rows = {"all flagged": flags.get("after", {})}
        rows.update({f: s for f, s in (flags.get("by_flag") or {}).items() if s.get("n")})
        parts.append(stats_table(rows, "flag (after calibration)"))
    return parts


def render(
    summary: dict[str, Any], figs: list[tuple[str, bytes]], frame_stats: pd.DataFrame
) -> str:
    """HTML text of the report."""
    n_used = (summary.get("overall", {}).get("after") or {}).get("n")
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>BlurTrack endpoint-error report</title><style>{REPORT_CSS}</style></head><body>",
        "<h1>BlurTrack endpoint-error report</h1>",
        f"<p>{summary['n_streaks']} streaks in {summary['n_frames']} frames"
        + (f"; {n_used} unflagged streaks the gyro covers are evaluated" if n_used else "")
        + ". Endpoint error: distance between the measured end of a streak and the end "
        "predicted by the gyro-driven blur model from its measured start.</p>",
    ]
    for w in summary.get("warnings", []):
        parts.append(f"<div class='warn'>{html.escape(str(w))}</div>")
    parts.append("<h2>Before and after calibration</h2>")
    parts.append(stats_table(summary["overall"], "calibration"))
    labels = summary.get("motion_model_labels", {})
    parts.append("<h2>Motion models (after calibration)</h2>")
    parts.append(
        stats_table({labels.get(k, k): v for k, v in summary["motion_models"].items()}, "model")
    )
    fit = summary.get("fit") or {}
    if fit.get("values"):
        parts.extend(fit_section_html(fit))
    if summary.get("flagged"):
        parts.extend(_flag_section(summary["flagged"], int(summary["n_streaks"])))
    parts.extend(shape_section(summary.get("shape_consistency")))
    for title, png in figs:
        parts.append(html_figure(title, png))
    ba = frame_stats[frame_stats["variant"].isin(["before", "after"])]
    if len(ba):
        piv = ba.pivot_table(index="frame", columns="variant", values="mean_px")
        cols = [c for c in ("before", "after") if c in piv.columns]
        rows = [[str(int(f))] + [fmt_px(float(piv.loc[f, c])) for c in cols] for f in piv.index]
        parts.append(
            "<details><summary><b>Per-frame mean endpoint error</b> "
            f"({len(rows)} frames)</summary>"
            + html_table(["frame"] + [f"{c} (px)" for c in cols], rows)
            + "</details>"
        )
    parts.append("</body></html>")
    return "\n".join(parts)
