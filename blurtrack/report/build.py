"""Assemble the endpoint-error report: CSV tables, summary.json and report.html.

Labels: ``before`` and ``after`` are the two calibrations (exact rotation, rolling shutter);
the motion-model comparison evaluates the ``after`` calibration with the source paper's per-axis
small-angle model (global shutter), exact rotation with a global shutter, and exact rotation
with rolling shutter, on the same streaks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.errors import BlurTrackError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.calibration import calibration_to_dict
from blurtrack.io.session import Session
from blurtrack.io.yamlio import write_text_atomic
from blurtrack.report import figures
from blurtrack.report.html import render
from blurtrack.report.metrics import (
    EXCLUDED_FLAGS,
    MOTION_VARIANTS,
    ReportError,
    endpoint_errors,
    flag_stats,
    per_frame,
    stats,
)
from blurtrack.report.shape import shape_summary

#: Frames drawn with their predicted and measured streaks.
N_OVERLAYS = 3


def json_safe(obj: Any) -> Any:
    """JSON-safe copy: NaN and infinities become ``null``."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    return obj


def _track_fn(session: Session, calib: Calibration, g: GyroTrace):
    """``df -> (N, 12, 2)`` predicted positions over each streak's exposure."""
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)
    exp_ns = session.frames["exposure_ns"].to_numpy(np.int64)
    t0 = int(ts[0])
    model = BlurModel(
        calib, GyroTrace(g.t_s - t0 * 1e-9, g.omega_radps, g.max_gap_s), check_coverage=False
    )
    cam = calib.camera

    def track(df: pd.DataFrame) -> np.ndarray:
        if len(df) == 0:
            return np.zeros((0, 12, 2))
        idx = df["frame"].to_numpy(np.int64)
        ft = (ts[idx] - t0) * 1e-9
        exp = exp_ns[idx] * 1e-9
        start = df[["start_x", "start_y"]].to_numpy(float)
        t_ref = cam.row_start_s(ft, start[:, 1])
        t_end = cam.row_start_s(ft, df["pred_end_y"].to_numpy(float)) + exp
        tau = np.linspace(0.0, 1.0, 12)
        times = t_ref[:, None] + (t_end - t_ref)[:, None] * tau[None, :]
        return model.point_track(start, t_ref, times)

    return track


def _unflagged(df: pd.DataFrame) -> pd.DataFrame:
    return df[~df["flagged"].to_numpy(bool)]


def worst_frames(errors: pd.DataFrame, n: int, min_streaks: int = 3) -> list[int]:
    """The ``n`` frames with the largest mean endpoint error (frames with at least
    ``min_streaks`` finite errors, or all frames when none has that many), worst first."""
    d = errors[np.isfinite(errors["error_px"].to_numpy())]
    g = d.groupby("frame")["error_px"].agg(["mean", "size"])
    if (g["size"] >= min_streaks).any():
        g = g[g["size"] >= min_streaks]
    return [int(f) for f in g.sort_values("mean", ascending=False).index[:n]]


def build_report(
    session: Session,
    table: pd.DataFrame,
    before: Calibration,
    after: Calibration,
    out_dir: str | Path,
    fit_summary: dict[str, Any] | None = None,
    n_overlays: int = N_OVERLAYS,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Write the report into ``out_dir``; returns the summary written to ``summary.json``.

    The gyro is resampled as the blur model does (:data:`~blurtrack.geometry.gyro.GYRO_UPSAMPLE`,
    the
    calibration's too), and a fitted gyro scale matrix in ``after`` is applied by the model.
    Streaks the detector flagged (:data:`~blurtrack.report.metrics.EXCLUDED_FLAGS`, the ones
    calibration leaves out) are kept in ``streak_errors.csv`` (column ``flagged``) and
    summarised per flag, but left out of every other statistic and figure. ``progress(done,
    total)`` is called after each stage.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if len(table) == 0:
        raise ReportError("no streaks to report on")
    total = 2 + len(MOTION_VARIANTS) + 6 + max(n_overlays, 0)
    done = 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(min(done, total), total)

    gyro = session.gyro()
    frames = session.frames
    errs: dict[str, pd.DataFrame] = {}
    for name, cal in (("before", before), ("after", after)):
        errs[name] = endpoint_errors(gyro, table, frames, cal)
        step()
    models: dict[str, pd.DataFrame] = {}
    for v in MOTION_VARIANTS:
        models[v.name] = endpoint_errors(gyro, table, frames, after, v.rotation_model, v.rolling)
        step()
    warnings: list[str] = []
    n_unc = int(np.count_nonzero(~errs["after"]["covered"]))
    if n_unc:
        warnings.append(
            f"{n_unc} streak(s) lie in exposures the gyro does not cover; they are "
            f"left out of the statistics"
        )
    if n_unc == len(table):
        raise ReportError("the gyro covers none of the exposures of the streak table")
    flagged = errs["after"]["flagged"].to_numpy(bool)
    if flagged.all():
        raise ReportError(
            f"every streak is flagged by the detector ({', '.join(EXCLUDED_FLAGS)}): "
            "nothing to report on"
        )
    use = {k: _unflagged(v) for k, v in errs.items()}
    use_models = {k: _unflagged(v) for k, v in models.items()}
    overall = {k: stats(v["error_px"].to_numpy()) for k, v in use.items()}
    model_stats = {k: stats(v["error_px"].to_numpy()) for k, v in use_models.items()}
    if overall["after"]["mean_px"] > overall["before"]["mean_px"]:
        warnings.append("the calibration under test predicts worse than the initial one")
    if fit_summary:
        warnings.extend(f"fit: {w}" for w in fit_summary.get("warnings", []))
    flags = {
        "excluded_flags": list(EXCLUDED_FLAGS)
        + (["not quality_ok"] if "quality_ok" in table.columns else []),
        "n_flagged": int(np.count_nonzero(flagged)),
        "after": stats(errs["after"]["error_px"].to_numpy()[flagged]),
        "by_flag": flag_stats(errs["after"], table),
    }

    long = pd.concat(
        [df.assign(variant=k) for k, df in {**errs, **models}.items()], ignore_index=True
    )
    long.to_csv(out / "streak_errors.csv", index=False, float_format="%.6g")
    fstats = per_frame({**use, **use_models})
    fstats.to_csv(out / "frame_errors.csv", index=False, float_format="%.6g")
    pd.DataFrame([{"variant": k, **v} for k, v in {**overall, **model_stats}.items()]).to_csv(
        out / "overall_errors.csv", index=False, float_format="%.6g"
    )

    w, h = after.camera.resolution
    labels = {v.name: v.label for v in MOTION_VARIANTS}
    figs: list[tuple[str, bytes]] = []
    for title, draw in (
        (
            "Endpoint error before and after calibration",
            lambda: figures.histogram_cdf(use, "before vs after calibration"),
        ),
        (
            "Per-frame mean endpoint error",
            lambda: figures.per_frame_plot(
                fstats[fstats["variant"].isin(["before", "after"])], "per frame"
            ),
        ),
        (
            "Endpoint error against image position (after)",
            lambda: figures.error_vs_position(use["after"], w, h, "after calibration"),
        ),
        (
            "Endpoint error against angular speed",
            lambda: figures.error_vs_speed(use, "before vs after"),
        ),
        (
            "Motion models on the same streaks (after calibration)",
            lambda: figures.model_bars(
                {labels[k]: v for k, v in model_stats.items()}, "motion models"
            ),
        ),
        (
            "Motion models: error distributions",
            lambda: figures.histogram_cdf(
                {labels[k]: v for k, v in use_models.items()}, "motion models"
            ),
        ),
    ):
        figs.append((title, draw()))
        step()
    covered = use["after"][use["after"]["covered"].to_numpy(bool)]
    track = _track_fn(session, after, gyro)
    n_drawn = int(covered["frame"].nunique())
    for rank, f in enumerate(worst_frames(covered, n_overlays), start=1):
        step()
        try:
            img = session.read_image(int(f))
        except BlurTrackError as exc:  # a missing or broken image only drops its figure
            warnings.append(f"frame {f}: image not drawn ({str(exc).splitlines()[0]})")
            continue
        sel = covered[covered["frame"] == f]
        figs.append(
            (
                f"Frame {f} (rank {rank} of {n_drawn} frames by mean error, worst first): "
                "measured and predicted streaks",
                figures.overlay(
                    img,
                    sel,
                    track,
                    f"frame {f}, after calibration, mean error {sel['error_px'].mean():.3f} px",
                ),
            )
        )
    if progress is not None:
        progress(total, total)

    summary = json_safe(
        {
            "n_streaks": len(table),
            "n_frames": int(table["frame"].nunique()),
            "n_uncovered": n_unc,
            "flagged": flags,
            "shape_consistency": shape_summary(table),
            "overall": overall,
            "motion_models": model_stats,
            "motion_model_labels": {v.name: v.label for v in MOTION_VARIANTS},
            "calibration_before": calibration_to_dict(before),
            "calibration_after": calibration_to_dict(after),
            "fit": fit_summary or {},
            "warnings": warnings,
            "gyro_upsample": GYRO_UPSAMPLE,
            "gyro_scale_matrix": after.gyro_scale_matrix,
            "files": [
                "report.html",
                "streak_errors.csv",
                "frame_errors.csv",
                "overall_errors.csv",
                "summary.json",
            ],
        }
    )
    write_text_atomic(out / "report.html", render(summary, figs, fstats))
    write_json_atomic(out / "summary.json", summary)  # strict JSON: NaN becomes null
    return summary
