"""Heat maps and blur trajectories of a recording (``blurtrack predict``): what GAMD needs to
deblur a real photo, from a session's gyro samples and a calibration.

Per frame: ``DIR/heat/<timestamp_ns>.npy`` (DESIGN heat maps, ``(6, H, W)`` float32, reference
time = mid-exposure of the centre row), and rows of ``DIR/trajectories.parquet`` with the
trajectory ``q(τ)`` of a coarse pixel grid (columns ``timestamp_ns, x, y, tau, qx, qy``, pixels).
Frames the gyro does not cover are refused before anything is written (one line naming them),
or skipped and listed with ``skip_uncovered``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.errors import CoverageError, SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.io import atomic
from blurtrack.io.session import Session
from blurtrack.synth.render import source_positions


@dataclass(frozen=True)
class PredictResult:
    """Frames written, frames skipped (timestamps), and statistics for ``summary.json``."""

    written: list[int]
    skipped: list[int]
    stats: dict[str, Any]


def session_calibration(session: Session, calib: Calibration) -> Calibration:
    """``calib`` at the session's resolution (scaled when only the size differs)."""
    have = calib.camera.resolution
    want = session.meta.camera.resolution
    if have == want:
        return calib
    factor = want[0] / have[0]
    if abs(have[1] * factor - want[1]) > 0.5:
        raise SynthesisError(
            f"calibration is for {have[0]}x{have[1]} but the session's frames "
            f"are {want[0]}x{want[1]} (another aspect ratio)"
        )
    return replace(calib, camera=calib.camera.scaled(factor))


def uncovered_frames(session: Session, model: BlurModel) -> list[int]:
    """Timestamps (ns) of frames whose exposure or reference time the gyro does not cover."""
    shift = model.calib.timeshift_cam_imu_s
    readout = model.camera.readout_s
    bad = []
    for ts, t, e in zip(
        session.frames["timestamp_ns"], session.frame_times_s, session.exposures_s, strict=True
    ):
        if not model.gyro.covers(t + shift, t + readout + e + shift):
            bad.append(int(ts))
    return bad


def _save_npy(path: Path, arr: np.ndarray) -> None:
    atomic.write_atomic(path, lambda f: np.save(f, arr, allow_pickle=False))


def predict_session(
    session: Session,
    calib: Calibration,
    out: str | Path,
    stride: int = 8,
    n_t: int = 16,
    grid: tuple[int, int] = (16, 9),
    skip_uncovered: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> PredictResult:
    """Write heat maps and trajectories of every frame of ``session`` under ``out``."""
    if session.imu_t_ns.size < 2:
        raise CoverageError(f"session {session.folder} has no gyro samples")
    model = BlurModel(session_calibration(session, calib), session.gyro())
    frames = session.frames
    if len(frames) == 0:
        raise SynthesisError(f"session {session.folder} has no frames")
    bad = uncovered_frames(session, model)
    if len(bad) == len(frames):  # --skip-uncovered would write nothing and score NaN
        raise CoverageError(
            f"the gyro covers none of the {len(frames)} frames' exposures; nothing to predict"
        )
    if bad and not skip_uncovered:
        shown = ", ".join(map(str, bad[:5])) + (" ..." if len(bad) > 5 else "")
        raise CoverageError(
            f"the gyro does not cover {len(bad)} of {len(frames)} frames "
            f"(timestamps ns: {shown}); --skip-uncovered predicts the others"
        )
    root = Path(out)
    (root / "heat").mkdir(parents=True, exist_ok=True)
    W, H = model.camera.resolution
    gu = np.round(np.linspace(0.0, W - 1.0, grid[0]))  # whole pixels: rows of the heat maps
    gv = np.round(np.linspace(0.0, H - 1.0, grid[1]))
    tau = np.linspace(0.0, 1.0, n_t)
    rows, written, fit_ok, fit_n, lengths = [], [], 0, 0, []
    todo = [i for i in range(len(frames)) if int(frames["timestamp_ns"].iloc[i]) not in bad]
    for k, i in enumerate(todo):
        ts = int(frames["timestamp_ns"].iloc[i])
        t, e = float(session.frame_times_s[i]), float(session.exposures_s[i])
        heat, err = model.heat_maps(t, e, n_t, None, stride)
        if not np.all(np.isfinite(heat)):
            raise SynthesisError(
                f"frame {ts}: the heat maps are not finite (calibration or gyro out of range)"
            )
        _save_npy(root / "heat" / f"{ts}.npy", heat)
        t_ref = model.default_reference_time(t, e)
        mx, my = source_positions(model, t, e, t_ref, gu, gv, tau)
        T = tau.size
        xx = np.broadcast_to(gu[None, None, :], mx.shape)
        yy = np.broadcast_to(gv[None, :, None], mx.shape)
        rows.append(
            pd.DataFrame(
                {
                    "timestamp_ns": np.full(mx.size, ts, np.int64),
                    "x": np.moveaxis(xx, 0, -1).reshape(-1),
                    "y": np.moveaxis(yy, 0, -1).reshape(-1),
                    "tau": np.tile(tau, mx.size // T),
                    "qx": np.moveaxis(mx - xx, 0, -1).reshape(-1),
                    "qy": np.moveaxis(my - yy, 0, -1).reshape(-1),
                }
            )
        )
        fit_ok += int(np.sum(err <= 0.5))
        fit_n += err.size
        lengths.append(float(np.median(np.hypot(heat[2] - heat[0], heat[3] - heat[1]))))
        written.append(ts)
        if progress:
            progress(k + 1, len(todo))
    table = (
        pd.concat(rows, ignore_index=True)
        if rows
        else pd.DataFrame(columns=["timestamp_ns", "x", "y", "tau", "qx", "qy"])
    )
    atomic.write_atomic(root / "trajectories.parquet", lambda f: table.to_parquet(f, index=False))
    stats = {
        "frames": len(frames),
        "predicted": len(written),
        "skipped": len(bad),
        "resolution": [W, H],
        "heat_stride": stride,
        "trajectory_samples": n_t,
        "bezier_fit_within_0.5px": fit_ok / fit_n if fit_n else math.nan,
        "median_blur_length_px": float(np.median(lengths)) if lengths else math.nan,
        "reference_time": "mid-exposure of the centre row",
    }
    return PredictResult(written, bad, stats)
