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
from typing import TYPE_CHECKING

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import CUE_SUBSTEP_S, FrameTiming

if TYPE_CHECKING:
    from blurtrack.geometry.calibration import Calibration
    from blurtrack.geometry.gyro import GyroTrace

#: Streaks used per frame and frames used (spread over the session): the scan's budget (180
#: streaks pin one parameter far below the exposure's resolution; each costs a model call per
#: trial shift).
MAX_STREAKS_PER_FRAME = 30
MAX_FRAMES = 6
#: Half-width of the scan about the session's initial shift (s): the initial shift may be tens
#: of milliseconds off.
SEARCH_S = 0.05


@dataclass(frozen=True)
class TimeshiftEstimate:
    """``timeshift_s`` (t_imu = t_cam + shift; None when ``status`` is ``undetermined``), the
    initial guess, the scanned grid and its costs, how many streaks were used, and ``status``:
    ``found``, or ``undetermined`` (the cost is flat: the gyro does not tell shifts apart)."""

    timeshift_s: float | None
    initial_s: float
    grid_s: np.ndarray
    cost: np.ndarray
    n_streaks: int
    status: str = "found"


@dataclass(frozen=True)
class _Batch:
    """The streaks used by the scan, all frames concatenated (one model call per shift)."""

    mid: np.ndarray
    end_a: np.ndarray
    end_b: np.ndarray
    sig2: np.ndarray
    frame_t_s: np.ndarray
    exposure_s: np.ndarray


def _costs(model: object, b: _Batch, deltas_s: np.ndarray) -> np.ndarray:
    """Orientation-free endpoint mismatch at each trial shift ``initial + delta`` (robust: each
    streak capped at 25), all shifts in one model call.

    A shift of the camera-IMU offset by ``delta`` is the same as evaluating the model (built
    with the initial shift) at camera times moved by ``delta``.
    """
    cam = model.camera  # type: ignore[attr-defined]
    n, g = b.mid.shape[0], deltas_s.size
    t_ref = (
        b.frame_t_s
        + cam.readout_s * np.clip(b.mid[:, 1], 0, cam.height - 1) / cam.height
        + 0.5 * b.exposure_s
    )
    d = np.repeat(deltas_s, n)
    start, end, _, _ = model.streak_endpoints(  # type: ignore[attr-defined]
        np.tile(b.mid, (g, 1)),
        np.tile(t_ref, g) + d,
        np.tile(b.frame_t_s, g) + d,
        np.tile(b.exposure_s, g),
    )
    A, B = np.tile(b.end_a, (g, 1)), np.tile(b.end_b, (g, 1))
    ca = np.sum((A - start) ** 2, axis=1) + np.sum((B - end) ** 2, axis=1)
    cb = np.sum((B - start) ** 2, axis=1) + np.sum((A - end) ** 2, axis=1)
    per = np.minimum(np.minimum(ca, cb) / np.tile(b.sig2, g), 25.0)
    return per.reshape(g, n).sum(axis=1)


def estimate_timeshift(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    calib: Calibration,
    gyro: GyroTrace,
    search_s: float = SEARCH_S,
    step_s: float = 0.003,
    model_gyro: GyroTrace | None = None,
    params: DetectParams | None = None,
) -> TimeshiftEstimate | None:
    """Scan shifts ``initial +- search_s``; None if too few long streaks or no gyro coverage,
    ``status="undetermined"`` (and no shift) if the cost does not depend on the shift.

    ``calib`` is a :class:`blurtrack.io.calibration.Calibration` (its ``timeshift_cam_imu_s``
    is the initial guess), ``gyro`` a :class:`blurtrack.geometry.gyro.GyroTrace`;
    ``model_gyro``: that trace already resampled as the blur model resamples it
    (``gyro.upsampled(GYRO_UPSAMPLE)``, when the caller has it: it is not resampled again).
    ``params``: its ``timeshift`` and ``orientation`` sections (defaults if None).
    """
    dp = params or DetectParams()
    ts = dp.timeshift
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
            (fs.length_px > ts.scan_min_length_px) & ~fs.flags["clipped"] & ~fs.flags["merged"]
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
            [
                (dp.orientation.gyro_sigma_px + ts.scan_sigma_rel * fs.length_px[sel]) ** 2
                for fs, sel, _ in parts
            ]
        ),
        frame_t_s=np.concatenate([np.full(len(sel), tm.t_s) for _, sel, tm in parts]),
        exposure_s=np.concatenate([np.full(len(sel), tm.exposure_s) for _, sel, tm in parts]),
    )

    if model_gyro is None:
        model = BlurModel(calib, gyro, max_substep_s=CUE_SUBSTEP_S, check_coverage=False)
    else:
        model = BlurModel(
            calib, model_gyro, max_substep_s=CUE_SUBSTEP_S, check_coverage=False, gyro_upsample=1
        )
    t_lo_s = float(np.min(batch.frame_t_s)) + initial
    t_hi_s = float(np.max(batch.frame_t_s + batch.exposure_s)) + readout + initial

    def costs_at(shifts: np.ndarray) -> np.ndarray:
        delta = shifts - initial
        ok = np.array([gyro.covers(t_lo_s + d, t_hi_s + d) for d in delta])  # type: ignore[attr-defined]
        cost = np.full(shifts.size, np.inf)
        if ok.any():
            cost[ok] = _costs(model, batch, delta[ok])
        return cost

    grid = initial + np.arange(-search_s, search_s + 1e-12, step_s)
    cost = costs_at(grid)
    if not np.any(np.isfinite(cost)):
        return None
    finite = cost[np.isfinite(cost)]
    if float(np.median(finite) - np.min(finite)) < ts.scan_min_contrast:
        return TimeshiftEstimate(None, initial, grid, cost, n, "undetermined")
    best = float(grid[int(np.argmin(cost))])
    fine = best + np.arange(-step_s, step_s + 1e-12, step_s / 4)
    fine_cost = costs_at(fine)
    best = float(fine[int(np.argmin(fine_cost))])
    return TimeshiftEstimate(
        timeshift_s=best,
        initial_s=initial,
        grid_s=np.concatenate([grid, fine]),
        cost=np.concatenate([cost, fine_cost]),
        n_streaks=n,
        status="found",
    )
