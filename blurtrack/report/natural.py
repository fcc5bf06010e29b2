"""The report of a natural-scene calibration (``blurtrack report`` on a natural session).

Three things a lab checks before trusting a calibration made from ordinary video:

* **Track errors before and after**: every feature track between consecutive frames
  (:mod:`blurtrack.features.tracks`) carried by the rotation model
  (:meth:`~blurtrack.geometry.blur_model.BlurModel.warp`) from its row's exposure midpoint in
  frame ``i`` to its row's in frame ``i + 1``; the error is the distance to where it was
  tracked. (Raw tracks: the calibration refines its own by equal-blur Lucas–Kanade,
  :mod:`blurtrack.features.equalblur`, so these errors are somewhat larger than the fit's.)
* **The axis search**: the 24 proper signed axis permutations' scores from the fit summary
  (``axes``), the winner and its margin over the runner-up.
* **Registered against gyro rotations**: per frame pair the rotation of the bearings
  ``K⁻¹x̃`` found from the images alone (Kabsch, one robust reweighting), against the same
  registration of the points the gyro and the calibration predict for the same tracks (so
  that a rolling shutter's row-to-row differences, a non-rigid warp a rigid rotation can
  only average, are averaged alike on both sides), and the angle between the two.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from blurtrack.features.tracks import FeatureTracks, track_frames
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import row_start_c
from blurtrack.geometry.rotation import so3_log
from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.calibration import calibration_to_dict
from blurtrack.io.session import Session
from blurtrack.io.yamlio import write_text_atomic
from blurtrack.report import figures
from blurtrack.report.html import REPORT_CSS, fit_section_html, html_figure, html_table, stats_table
from blurtrack.report.metrics import ReportError, stats

#: Fewest tracks of a pair whose rotation is registered.
MIN_PAIR_TRACKS = 8


def _model(session: Session, calib: Calibration) -> tuple[BlurModel, np.ndarray, np.ndarray]:
    """Blur model on the session's relative clock, frame times and exposures (s)."""
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)
    g = session.gyro()
    t0 = int(ts[0])
    model = BlurModel(
        calib, GyroTrace(g.t_s - t0 * 1e-9, g.omega_radps, g.max_gap_s), check_coverage=False
    )
    exp = session.frames["exposure_ns"].to_numpy(np.int64) * 1e-9
    return model, (ts - t0) * 1e-9, exp


def _covered(model: BlurModel, t_a: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    g = model.gyro
    s = model.calib.timeshift_cam_imu_s
    return (np.minimum(t_a, t_b) + s >= g.t_s[0]) & (np.maximum(t_a, t_b) + s <= g.t_s[-1])


def _point_times(
    tracks: FeatureTracks, t: np.ndarray, e: np.ndarray, cam: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Each track's two points dated at their rows' exposure midpoints (s, camera clock)."""
    ta = row_start_c(t[tracks.frame_a], tracks.pts_a[:, 1], cam.readout_s, cam.height)
    tb = row_start_c(t[tracks.frame_b], tracks.pts_b[:, 1], cam.readout_s, cam.height)
    return ta + e[tracks.frame_a] / 2, tb + e[tracks.frame_b] / 2


def track_errors(tracks: FeatureTracks, session: Session, calib: Calibration) -> pd.DataFrame:
    """Per track: frames, points and the rotation model's error (px; NaN where the gyro does
    not cover the interval)."""
    model, t, e = _model(session, calib)
    cam = calib.camera
    a = tracks.frame_a
    ta, tb = _point_times(tracks, t, e, cam)
    cov = _covered(model, ta, tb)
    err = np.full(len(tracks), np.nan)
    if np.any(cov):
        pred = model.warp(tracks.pts_a[cov], ta[cov], tb[cov])
        err[cov] = np.linalg.norm(pred - tracks.pts_b[cov], axis=1)
    return pd.DataFrame(
        {
            "frame": a,
            "x": tracks.pts_a[:, 0],
            "y": tracks.pts_a[:, 1],
            "x_next": tracks.pts_b[:, 0],
            "y_next": tracks.pts_b[:, 1],
            "error_px": err,
        }
    )


def register_rotation(bearings_a: np.ndarray, bearings_b: np.ndarray) -> np.ndarray:
    """``Q`` (3, 3) with ``bearings_b ≈ Q bearings_a`` (Kabsch, proper), reweighted once
    without the bearings whose misfit exceeds 3× the median."""
    keep = np.ones(len(bearings_a), bool)
    Q = np.eye(3)
    for _ in range(2):
        H = bearings_a[keep].T @ bearings_b[keep]
        U, _s, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        Q = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
        r = np.linalg.norm(bearings_b - bearings_a @ Q.T, axis=1)
        keep = r <= 3 * max(float(np.median(r)), 1e-12)
    return Q


def _bearings(cam: Any, px: np.ndarray) -> np.ndarray:
    b = cam.unproject(px)
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def pair_rotations(tracks: FeatureTracks, session: Session, calib: Calibration) -> pd.DataFrame:
    """Per frame pair: the rotation registered from the tracks and the one registered the
    same way from the gyro's prediction of the same tracks (rotation vectors, deg, camera
    frame; the same fit on both sides, so the rolling shutter's row-to-row differences
    average alike), and the angle between the two (deg and px at ``fx``)."""
    model, t, e = _model(session, calib)
    cam = calib.camera
    a = tracks.frame_a
    ta, tb = _point_times(tracks, t, e, cam)
    cov = _covered(model, ta, tb)
    rows = []
    for f in np.unique(a):
        sel = a == f
        if np.count_nonzero(sel) < MIN_PAIR_TRACKS:
            continue
        ba = _bearings(cam, tracks.pts_a[sel])
        Q = register_rotation(ba, _bearings(cam, tracks.pts_b[sel]))
        img = np.degrees(so3_log(Q.T))
        row: dict[str, Any] = {"frame": int(f), "tracks": int(np.count_nonzero(sel))}
        row.update({f"image_deg_{k}": float(v) for k, v in zip("xyz", img, strict=True)})
        if np.all(cov[sel]):
            pred = model.warp(tracks.pts_a[sel], ta[sel], tb[sel])
            G = register_rotation(ba, _bearings(cam, pred))
            gyr = np.degrees(so3_log(G.T))
            diff = math.degrees(float(np.linalg.norm(so3_log(Q @ G.T))))
        else:
            gyr, diff = np.full(3, np.nan), float("nan")
        row.update({f"gyro_deg_{k}": float(v) for k, v in zip("xyz", gyr, strict=True)})
        row["image_deg"] = float(np.linalg.norm(img))
        row["gyro_deg"] = float(np.linalg.norm(gyr))
        row["difference_deg"] = diff
        row["difference_px"] = math.radians(diff) * cam.intrinsics[0]
        rows.append(row)
    return pd.DataFrame(rows)


def agreement_plot(pairs: dict[str, pd.DataFrame]) -> bytes:
    """Registered and gyro rotation angle per pair (top) and their difference (bottom)."""
    fig, (top, bot) = plt.subplots(2, 1, figsize=(11, 5), sharex=True)
    first = next(iter(pairs.values()))
    top.plot(first["frame"], first["image_deg"], "k.-", ms=3, label="registered (images)")
    for (label, df), c in zip(pairs.items(), figures.COLORS, strict=False):
        top.plot(df["frame"], df["gyro_deg"], ".-", color=c, ms=3, label=f"gyro ({label})")
        bot.plot(df["frame"], df["difference_deg"], ".-", color=c, ms=3, label=label)
    top.set_ylabel("inter-frame rotation (deg)")
    bot.set_ylabel("angle between them (deg)")
    bot.set_yscale("log")
    bot.set_xlabel("frame pair (first frame)")
    for ax in (top, bot):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    top.set_title("registered and gyro rotations per frame pair")
    return figures._png(fig)


def axis_table(axes: dict[str, Any]) -> str:
    """The 24 candidates, best first (HTML)."""
    cands = axes.get("candidates") or []
    best = float(cands[0]["score_px"]) if cands else float("nan")
    rows = [
        [
            str(i),
            "<code>" + " ".join(str([int(v) for v in r]) for r in c["R_cam_imu"]) + "</code>",
            f"{float(c['timeshift_s']) * 1e3:+.1f}",
            f"{float(c['score_px']):.3f}",
            f"{float(c['score_px']) / best:.2f}" if best > 0 else "–",
        ]
        for i, c in enumerate(cands, start=1)
    ]
    return html_table(["rank", "R_cam_imu (rows)", "shift (ms)", "score (px)", "/ winner"], rows)


def _html(summary: dict[str, Any], figs: list[tuple[str, bytes]]) -> str:
    nat = summary["natural"]
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>BlurTrack natural-scene report</title><style>{REPORT_CSS}</style></head><body>",
        "<h1>BlurTrack natural-scene report</h1>",
        f"<p>{nat['n_tracks']} feature tracks in {nat['n_pairs']} frame pairs. Track error: "
        "distance between where a feature was tracked in the next frame and where the "
        "gyro-driven rotation model carries it (rolling-shutter row times).</p>",
    ]
    for w in summary["warnings"]:
        parts.append(f"<div class='warn'>{html.escape(str(w))}</div>")
    parts.append("<h2>Track errors before and after calibration</h2>")
    parts.append(stats_table(nat["track_errors"], "calibration"))
    tr = (summary.get("fit") or {}).get("translation") or {}
    if tr.get("mode") not in (None, "none"):
        parts.append(
            f"<p>The fit modelled the camera's translation ({html.escape(str(tr['mode']))}): "
            "the rotation-only "
            "track errors above include the parallax it explained.</p>"
        )
    ax = nat.get("axes")
    if ax:
        w = ax["winner"]
        parts.append(
            f"<h2>Axis search</h2><p>{html.escape(str(ax['source']))}, {ax['n_pairs']} frame "
            "pairs, median "
            f"rotation {ax['motion_px']:.2f} px. Winner "
            f"<code>{[[int(v) for v in r] for r in w['R_cam_imu']]}</code>, score "
            f"{w['score_px']:.3f} px, margin over the runner-up <b>{ax['margin']:.2f}</b>.</p>"
        )
        parts.append(axis_table(ax))
    ag = nat["agreement"]
    parts.append(
        "<h2>Registered and gyro rotations</h2><p>Median angle between the rotation "
        "registered from the images and the gyro's, per frame pair: "
        + ", ".join(f"{k} {v['median_deg']:.4f}° ({v['median_px']:.3f} px)" for k, v in ag.items())
        + ".</p>"
    )
    fit = summary.get("fit") or {}
    if fit.get("values"):
        parts.extend(fit_section_html(fit))
    for title, png in figs:
        parts.append(html_figure(title, png))
    parts.append("</body></html>")
    return "\n".join(parts)


def build_natural_report(
    session: Session,
    before: Calibration,
    after: Calibration,
    out_dir: str | Path,
    fit_summary: dict[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Write ``report.html``, ``summary.json``, ``track_errors.csv`` and
    ``pair_rotations.csv`` into ``out_dir``; returns the summary."""
    from blurtrack.report.build import json_safe

    n = len(session.frames)
    if n < 2:
        raise ReportError(f"a natural-scene report needs at least 2 frames, got {n}")
    tracks = track_frames(session.read_image, n, progress=progress)
    if len(tracks) == 0:
        raise ReportError("no feature tracks between the frames: nothing to report on")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cals = {"before": before, "after": after}
    errs = {k: track_errors(tracks, session, c) for k, c in cals.items()}
    pairs = {k: pair_rotations(tracks, session, c) for k, c in cals.items()}
    warnings: list[str] = []
    n_unc = int(np.count_nonzero(~np.isfinite(errs["after"]["error_px"].to_numpy())))
    if n_unc:
        warnings.append(f"{n_unc} track(s) lie outside the gyro's coverage and are left out")
    if fit_summary:
        warnings.extend(f"fit: {w}" for w in fit_summary.get("warnings", []))
    overall = {k: stats(v["error_px"].to_numpy()) for k, v in errs.items()}
    agreement = {}
    for k, df in pairs.items():
        d = df["difference_deg"].to_numpy(float) if len(df) else np.zeros(0)
        d = d[np.isfinite(d)]
        med = float(np.median(d)) if d.size else float("nan")
        agreement[k] = {
            "pairs": int(d.size),
            "median_deg": med,
            "median_px": math.radians(med) * after.camera.intrinsics[0],
            "max_deg": float(d.max()) if d.size else float("nan"),
        }
    pd.concat([v.assign(calibration=k) for k, v in errs.items()]).to_csv(
        out / "track_errors.csv", index=False, float_format="%.6g"
    )
    pd.concat([v.assign(calibration=k) for k, v in pairs.items()]).to_csv(
        out / "pair_rotations.csv", index=False, float_format="%.6g"
    )
    figs = [
        (
            "Track error before and after calibration",
            figures.histogram_cdf(errs, "feature tracks, before vs after"),
        ),
        ("Registered and gyro rotations per frame pair", agreement_plot(pairs)),
    ]
    summary = json_safe(
        {
            "target": "natural",
            "natural": {
                "n_tracks": len(tracks),
                "n_pairs": int(np.count_nonzero(tracks.per_pair)),
                "track_errors": overall,
                "axes": (fit_summary or {}).get("axes"),
                "agreement": agreement,
            },
            "calibration_before": calibration_to_dict(before),
            "calibration_after": calibration_to_dict(after),
            "fit": fit_summary or {},
            "warnings": warnings,
            "files": [
                "report.html",
                "track_errors.csv",
                "pair_rotations.csv",
                "summary.json",
            ],
        }
    )
    write_text_atomic(out / "report.html", _html(summary, figs))
    write_json_atomic(out / "summary.json", summary)
    return summary
