"""A coarse camera–IMU time shift from the streaks themselves, for start/end resolution.

The session's initial time shift may be tens of milliseconds off, comparable with the
exposure: the gyro then predicts the motion of the wrong instant, and its start/end verdict
is worthless. Whatever the orientation, a streak's two ends must match the predicted two ends;
that orientation-free cost, summed over many long streaks, is minimal at the right shift.
We scan it on a grid and refine around the minimum. This is only a helper for the
orientation cue (calibration fits the shift properly, with everything else).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.orientation import GYRO_SIGMA_PX, FrameTiming

#: Streaks used per frame and frames used (spread over the session).
MAX_STREAKS_PER_FRAME = 30
MAX_FRAMES = 6
MIN_LENGTH_PX = 5.0


@dataclass(frozen=True)
class TimeshiftEstimate:
    """``timeshift_s`` (t_imu = t_cam + shift), the initial guess, the scanned grid and its
    costs, and how many streaks were used."""

    timeshift_s: float
    initial_s: float
    grid_s: np.ndarray
    cost: np.ndarray
    n_streaks: int


@dataclass(frozen=True)
class _Batch:
    """The streaks used by the scan, all frames concatenated (one model call per shift)."""

    mid: np.ndarray
    end_a: np.ndarray
    end_b: np.ndarray
    sig2: np.ndarray
    frame_t_s: np.ndarray
    exposure_s: np.ndarray


def _cost(model: object, b: _Batch) -> float:
    """Orientation-free endpoint mismatch (robust: each streak capped at 25)."""
    cam = model.camera  # type: ignore[attr-defined]
    t_ref = (
        b.frame_t_s
        + cam.readout_s * np.clip(b.mid[:, 1], 0, cam.height - 1) / cam.height
        + 0.5 * b.exposure_s
    )
    start, end, _, _ = model.streak_endpoints(  # type: ignore[attr-defined]
        b.mid, t_ref, b.frame_t_s, b.exposure_s
    )
    ca = np.sum((b.end_a - start) ** 2, axis=1) + np.sum((b.end_b - end) ** 2, axis=1)
    cb = np.sum((b.end_b - start) ** 2, axis=1) + np.sum((b.end_a - end) ** 2, axis=1)
    return float(np.sum(np.minimum(np.minimum(ca, cb) / b.sig2, 25.0)))


def estimate_timeshift(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    calib: object,
    gyro: object,
    search_s: float = 0.05,
    step_s: float = 0.003,
) -> TimeshiftEstimate | None:
    """Scan shifts ``initial +- search_s``; None if too few long streaks or no gyro coverage.

    ``calib`` is a :class:`blurtrack.io.calibration.Calibration` (its ``timeshift_cam_imu_s``
    is the initial guess), ``gyro`` a :class:`blurtrack.geometry.gyro.GyroTrace`.
    """
    from blurtrack.errors import CoverageError
    from blurtrack.geometry.blur_model import BlurModel

    initial = float(calib.timeshift_cam_imu_s)  # type: ignore[attr-defined]
    # Frames whose whole exposure (plus a readout's worth) stays covered for every shift.
    t_lo = float(gyro.t_s[0]) + search_s  # type: ignore[attr-defined]
    t_hi = float(gyro.t_s[-1]) - search_s  # type: ignore[attr-defined]
    readout = float(calib.camera.readout_s)  # type: ignore[attr-defined]
    usable = [
        k
        for k, (fs, tm) in enumerate(zip(frames, timings, strict=True))
        if len(fs)
        and t_lo <= tm.t_s + initial
        and tm.t_s + initial + tm.exposure_s + readout <= t_hi
    ]
    if not usable:
        return None
    pick = np.unique(np.linspace(0, len(usable) - 1, min(MAX_FRAMES, len(usable))).round())
    parts = []
    for k in (usable[int(i)] for i in pick):
        fs = frames[k]
        long = np.flatnonzero(
            (fs.length_px > MIN_LENGTH_PX) & ~fs.flags["clipped"] & ~fs.flags["merged"]
        )
        if long.size:
            sel = np.unique(
                long[
                    np.linspace(0, long.size - 1, min(MAX_STREAKS_PER_FRAME, long.size))
                    .round()
                    .astype(int)
                ]
            )
            parts.append((fs, sel, timings[k]))
    n = sum(len(p[1]) for p in parts)
    if n < 5:
        return None
    batch = _Batch(
        mid=np.concatenate([fs.time_mid[sel] for fs, sel, _ in parts]),
        end_a=np.concatenate([fs.end_a[sel] for fs, sel, _ in parts]),
        end_b=np.concatenate([fs.end_b[sel] for fs, sel, _ in parts]),
        sig2=np.concatenate(
            [(GYRO_SIGMA_PX + 0.1 * fs.length_px[sel]) ** 2 for fs, sel, _ in parts]
        ),
        frame_t_s=np.concatenate([np.full(len(sel), tm.t_s) for _, sel, tm in parts]),
        exposure_s=np.concatenate([np.full(len(sel), tm.exposure_s) for _, sel, tm in parts]),
    )

    def cost_at(shift: float) -> float:
        model = BlurModel(calib.with_(timeshift_cam_imu_s=shift), gyro)  # type: ignore[attr-defined]
        try:
            return _cost(model, batch)
        except CoverageError:
            return float("inf")

    grid = initial + np.arange(-search_s, search_s + 1e-12, step_s)
    cost = np.array([cost_at(s) for s in grid])
    if not np.any(np.isfinite(cost)):
        return None
    best = float(grid[int(np.argmin(cost))])
    fine = best + np.arange(-step_s, step_s + 1e-12, step_s / 4)
    fine_cost = np.array([cost_at(s) for s in fine])
    best = float(fine[int(np.argmin(fine_cost))])
    return TimeshiftEstimate(
        timeshift_s=best,
        initial_s=initial,
        grid_s=np.concatenate([grid, fine]),
        cost=np.concatenate([cost, fine_cost]),
        n_streaks=n,
    )
