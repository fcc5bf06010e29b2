"""Endpoint errors of measured streaks under a calibration (numpy, :class:`BlurModel`).

The predicted streak of a measured one is anchored at its measured start: the start pixel at its
row's start of exposure (``t_s = frame_t + readout · y_s / H``) is carried through the exposure
by the gyro-driven model (:meth:`BlurModel.streak_endpoints`), and the endpoint error is the
distance between the predicted and the measured end (pixels).

Motion models compared on the same streaks: the source paper's per-axis small-angle sum with a
global shutter (as the paper), exact rotation with a global shutter, small angles with rolling
shutter (isolates the integration error), and exact rotation with rolling shutter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from blurtrack.errors import BlurTrackError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import ROW_TIME_ITERATIONS


class ReportError(BlurTrackError):
    """A report cannot be produced from the given inputs."""


@dataclass(frozen=True)
class MotionVariant:
    """A motion model to compare: rotation integration and whether rolling shutter is used."""

    name: str
    label: str
    rotation_model: str
    rolling: bool


MOTION_VARIANTS = (
    MotionVariant(
        "paper_small_angle", "paper: per-axis small angles, global shutter", "small_angle", False
    ),
    MotionVariant("exact_global", "exact rotation, global shutter", "exact", False),
    MotionVariant(
        "small_angle_rolling", "per-axis small angles + rolling shutter", "small_angle", True
    ),
    MotionVariant("exact_rolling", "exact rotation + rolling shutter", "exact", True),
)


#: Detector flags whose streaks calibration leaves out of tables without ``quality_ok``
#: (:func:`calib.data.streaks_from_table`); the report lists them separately and keeps them
#: out of every statistic and figure.
EXCLUDED_FLAGS: tuple[str, ...] = ("clipped", "saturated", "merged")


def flagged_mask(table: pd.DataFrame) -> np.ndarray:
    """``(N,)`` bool: the streak is clipped, merged or (tables that have the column) not
    ``quality_ok``, or, in older tables without it, saturated: as calibration decides (a
    saturated core whose ends are measured well stays ``quality_ok``)."""
    m = np.zeros(len(table), dtype=bool)
    has_ok = "quality_ok" in table.columns
    for f in EXCLUDED_FLAGS:
        if f in table.columns and not (has_ok and f == "saturated"):
            m |= table[f].to_numpy(bool)
    if has_ok:
        m |= ~table["quality_ok"].to_numpy(bool)
    return m


def flag_stats(errors: pd.DataFrame, table: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Per detector flag (:data:`EXCLUDED_FLAGS`): count and endpoint-error statistics of the
    streaks that carry it (``errors`` row-aligned with ``table``); a streak may carry several."""
    out: dict[str, dict[str, float]] = {}
    for f in EXCLUDED_FLAGS:
        if f in table.columns:
            sel = table[f].to_numpy(bool)
            out[f] = stats(errors["error_px"].to_numpy()[sel])
    return out


def _relative(gyro: GyroTrace, t0_s: float) -> GyroTrace:
    return GyroTrace(gyro.t_s - t0_s, gyro.omega_radps, gyro.max_gap_s)


def predict_end(
    model: BlurModel,
    start: np.ndarray,
    t_ref_s: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
) -> np.ndarray:
    """End ``(N, 2)`` of the streaks that start at ``start (N, 2)`` at ``t_ref_s`` (camera clock).

    The same fixed-point row-time solve as :func:`blurtrack.geometry.kernels.rolling_endpoint_c`
    (and as many iterations), anchored at the measured start, through :meth:`BlurModel.warp`
    (the model's ``rotation_model`` and sub-steps).
    """
    cam = model.calib.camera
    t = cam.row_start_s(frame_t_s, start[:, 1]) + exposure_s
    for _ in range(ROW_TIME_ITERATIONS):
        p = model.warp(start, t_ref_s, t)
        t = cam.row_start_s(frame_t_s, p[:, 1]) + exposure_s
    return model.warp(start, t_ref_s, t)


def endpoint_errors(
    gyro: GyroTrace,
    table: pd.DataFrame,
    frames: pd.DataFrame,
    calib: Calibration,
    rotation_model: str = "exact",
    rolling: bool = True,
) -> pd.DataFrame:
    """Per-streak predicted end and endpoint error.

    Args:
        gyro: session gyro trace (absolute IMU clock, s).
        table: validated streak table (:mod:`blurtrack.io.streaks`).
        frames: the session's frame table (``timestamp_ns``, ``exposure_ns``).
        calib: the calibration to evaluate; ``rolling=False`` forces a global shutter.

    Returns:
        DataFrame: ``frame, streak_id, start_x, start_y, end_x, end_y, pred_end_x, pred_end_y,
        error_px, omega_radps`` (angular speed at mid-exposure), ``covered`` (False where the
        gyro does not cover the exposure; error NaN there) and ``flagged`` (the detector
        flagged the streak, :data:`EXCLUDED_FLAGS`).
    """
    if len(table) == 0:
        raise ReportError("the streak table is empty")
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    exp_ns = frames["exposure_ns"].to_numpy(np.int64)
    idx = table["frame"].to_numpy(np.int64)
    if np.any((idx < 0) | (idx >= ts.size)):
        raise ReportError("streak table names frames the session does not have")
    t0_ns = int(ts[0])
    ft = (ts[idx] - t0_ns) * 1e-9
    exp = exp_ns[idx] * 1e-9
    cal = calib if rolling else calib.with_(readout_s=0.0)
    g = _relative(gyro, t0_ns * 1e-9)
    model = BlurModel(cal, g, rotation_model=rotation_model, check_coverage=False)
    cam = cal.camera
    shift = cal.timeshift_cam_imu_s
    covered = np.zeros(idx.size, dtype=bool)
    for f in np.unique(idx):
        sel = idx == f
        lo = float(ft[sel][0] + shift)
        covered[sel] = g.covers(lo, lo + cam.readout_s + float(exp[sel].max()))
    start = table[["start_x", "start_y"]].to_numpy(float)
    end = table[["end_x", "end_y"]].to_numpy(float)
    pred = np.full_like(end, np.nan)
    speed = np.full(idx.size, np.nan)
    if np.any(covered):
        c = covered
        t_ref = cam.row_start_s(ft[c], start[c, 1])
        pred[c] = predict_end(model, start[c], t_ref, ft[c], exp[c])
        w = np.stack(model.omega_cam_at(t_ref + exp[c] / 2), axis=1)
        speed[c] = np.linalg.norm(w, axis=1)
    err = np.linalg.norm(pred - end, axis=1)
    return pd.DataFrame(
        {
            "frame": idx,
            "timestamp_ns": ts[idx],
            "streak_id": table["streak_id"].to_numpy(np.int64),
            "start_x": start[:, 0],
            "start_y": start[:, 1],
            "end_x": end[:, 0],
            "end_y": end[:, 1],
            "pred_end_x": pred[:, 0],
            "pred_end_y": pred[:, 1],
            "error_px": err,
            "omega_radps": speed,
            "covered": covered,
            "flagged": flagged_mask(table),
        }
    )


def stats(errors_px: np.ndarray) -> dict[str, float]:
    """Mean, median, 95th percentile, RMS and count of finite errors (pixels)."""
    e = np.asarray(errors_px, float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {
            "n": 0,
            "mean_px": float("nan"),
            "median_px": float("nan"),
            "p95_px": float("nan"),
            "rms_px": float("nan"),
        }
    return {
        "n": int(e.size),
        "mean_px": float(e.mean()),
        "median_px": float(np.median(e)),
        "p95_px": float(np.percentile(e, 95)),
        "rms_px": float(np.sqrt(np.mean(e**2))),
    }


def per_frame(errors: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per-frame statistics of each labelled error table, one row per (label, frame)."""
    rows = []
    for label, df in errors.items():
        for (frame, ts), grp in df.groupby(["frame", "timestamp_ns"], sort=True):
            rows.append(
                {
                    "variant": label,
                    "frame": int(frame),
                    "timestamp_ns": int(ts),
                    **stats(grp["error_px"].to_numpy()),
                }
            )
    return pd.DataFrame(rows)
