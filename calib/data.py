"""Calibration input: measured streak endpoints with their frame timing, and the gyro trace.

Times are shifted by a common origin ``t0_s`` (the first frame's timestamp) so that the solver
works with small numbers: camera times ``t - t0`` and IMU times ``t_imu - t0`` keep
``t_imu = t_cam + shift`` unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from calib.errors import CalibError


@dataclass(frozen=True)
class StreakSet:
    """Streaks as flat arrays (one entry per streak).

    Attributes:
        start, end: ``(N, 2)`` measured endpoints, pixels.
        frame_t_s: ``(N,)`` frame timestamp (camera clock, relative to ``t0_s``), s.
        exposure_s: ``(N,)`` exposure time, s.
        frame: ``(N,)`` frame index in the session.
        streak_id: ``(N,)`` streak number (dot id for simulated sessions).
        t0_s: absolute camera time of the origin, s.
        centre: optional ``(N, K, 2)`` points of the measured centre line (pixels, ordered
            start to end; see :func:`centre_points`); NaN rows: no usable centre line.
        time_row: optional ``(N, 2)`` rows (pixels) whose rolling-shutter start times date
            the start and the end; ``None``: the points' own rows ``start[:, 1]``,
            ``end[:, 1]`` (a streak). Inter-frame tracks (:mod:`calib.tracks`) date a time
            midpoint by the mean row of its streak's ends instead.
        mid: optional ``(N, 2)`` time midpoints (the point that halves the streak's light,
            where the dot was at the middle of its exposure), pixels: what inter-frame
            tracks are made of.
        dropped_quality: how many streaks :func:`streaks_from_table` left out because
            detection marked them not ``quality_ok`` (and no other dropped flag).
    """

    start: np.ndarray
    end: np.ndarray
    frame_t_s: np.ndarray
    exposure_s: np.ndarray
    frame: np.ndarray
    streak_id: np.ndarray
    t0_s: float = 0.0
    centre: np.ndarray | None = None
    time_row: np.ndarray | None = None
    mid: np.ndarray | None = None
    dropped_quality: int = 0

    def __post_init__(self) -> None:
        n = len(self.frame)
        if self.mid is not None:
            md = np.asarray(self.mid, dtype=float)
            if md.shape != (n, 2) or not np.all(np.isfinite(md)):
                raise CalibError(f"streak time midpoints must be finite with shape ({n}, 2)")
            object.__setattr__(self, "mid", md)
        if self.time_row is not None:
            tr = np.asarray(self.time_row, dtype=float)
            if tr.shape != (n, 2) or not np.all(np.isfinite(tr)):
                raise CalibError(f"streak time rows must be finite with shape ({n}, 2)")
            object.__setattr__(self, "time_row", tr)
        if self.centre is not None:
            c = np.asarray(self.centre, dtype=float)
            if c.ndim != 3 or c.shape[0] != n or c.shape[2] != 2 or c.shape[1] < 1:
                raise CalibError(f"streak centre points must have shape ({n}, K, 2)")
            if np.any(np.isinf(c)) or np.any(
                np.isnan(c).any(axis=(1, 2)) != np.isnan(c).all(axis=(1, 2))
            ):
                raise CalibError("streak centre points must be finite (or a whole row NaN)")
            object.__setattr__(self, "centre", c)
        for name in ("start", "end"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n, 2) or not np.all(np.isfinite(a)):
                raise CalibError(f"streak {name} points must be finite with shape ({n}, 2)")
            object.__setattr__(self, name, a)
        for name in ("frame_t_s", "exposure_s"):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise CalibError(f"streak {name} must be {n} finite numbers")
            object.__setattr__(self, name, a)
        if np.any(self.exposure_s <= 0):
            raise CalibError("streak exposures must be positive")
        object.__setattr__(self, "frame", np.asarray(self.frame, dtype=np.int64).reshape(-1))
        object.__setattr__(
            self, "streak_id", np.asarray(self.streak_id, dtype=np.int64).reshape(-1)
        )

    def __len__(self) -> int:
        return int(self.frame.size)

    @property
    def n_frames(self) -> int:
        return int(np.unique(self.frame).size)

    @property
    def rows(self) -> np.ndarray:
        """``(N, 2)`` rows dating the start and the end (see ``time_row``)."""
        if self.time_row is not None:
            return self.time_row
        return np.stack([self.start[:, 1], self.end[:, 1]], axis=1)

    @property
    def length_px(self) -> np.ndarray:
        return np.linalg.norm(self.end - self.start, axis=1)

    def subset(self, mask: np.ndarray) -> StreakSet:
        m = np.asarray(mask)
        return replace(
            self,
            start=self.start[m],
            end=self.end[m],
            frame_t_s=self.frame_t_s[m],
            exposure_s=self.exposure_s[m],
            frame=self.frame[m],
            streak_id=self.streak_id[m],
            centre=None if self.centre is None else self.centre[m],
            time_row=None if self.time_row is None else self.time_row[m],
            mid=None if self.mid is None else self.mid[m],
        )

    def flipped(self) -> StreakSet:
        """The same streaks with start and end swapped (centre points reversed)."""
        return replace(
            self,
            start=self.end,
            end=self.start,
            centre=None if self.centre is None else self.centre[:, ::-1],
            time_row=None if self.time_row is None else self.time_row[:, ::-1],
        )

    def reoriented(self, mask: np.ndarray) -> StreakSet:
        """Start and end swapped where ``mask`` (N,) is true."""
        m = np.asarray(mask, dtype=bool)[:, None]
        c = self.centre
        if c is not None:
            c = np.where(m[:, :, None], c[:, ::-1], c)
        tr = self.time_row
        if tr is not None:
            tr = np.where(m, tr[:, ::-1], tr)
        return replace(
            self,
            start=np.where(m, self.end, self.start),
            end=np.where(m, self.start, self.end),
            centre=c,
            time_row=tr,
        )


def centre_points(polyline: object, k: int) -> np.ndarray:
    """``k`` points ``(k, 2)`` of a centre line at arc-length fractions ``j / (k + 1)``.

    ``polyline``: ordered ``[[x, y], ...]`` (pixels). Fewer than two distinct points: a NaN
    row (no usable centre line). Interior points only: the endpoints have their own residual.

    >>> centre_points([[0, 0], [4, 0], [4, 4]], 3).tolist()
    [[2.0, 0.0], [4.0, 0.0], [4.0, 2.0]]
    """
    try:
        P = np.asarray(polyline, dtype=float).reshape(-1, 2)
    except (TypeError, ValueError):
        raise CalibError("a streak centre line is not a list of [x, y] points") from None
    if not np.all(np.isfinite(P)):
        raise CalibError("a streak centre line has NaN or infinite points")
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if P.shape[0] < 2 or arc[-1] <= 0:
        return np.full((k, 2), np.nan)
    s = arc[-1] * np.arange(1, k + 1) / (k + 1)
    return np.stack([np.interp(s, arc, P[:, 0]), np.interp(s, arc, P[:, 1])], axis=1)


def streaks_from_table(
    table: pd.DataFrame, frames: pd.DataFrame, drop_flagged: bool = True, centre_k: int = 0
) -> StreakSet:
    """A :class:`StreakSet` from a validated streak table and the session's frame table.

    ``frames`` has ``timestamp_ns`` and ``exposure_ns`` columns (``Session.frames``). When
    ``drop_flagged``, streaks flagged clipped or merged are left out, and so are those whose
    ``quality_ok`` is false where the table has that column (counted in ``dropped_quality``;
    a saturated core whose ends are measured well stays ``quality_ok``), or, in older tables
    without it, those flagged saturated. ``centre_k > 0``
    also resamples each row's ``centerline`` to that many interior points (:func:`centre_points`).
    """
    df = table
    dropped_quality = 0
    if drop_flagged and len(df):
        df = df[~(df["clipped"] | df["merged"])]
        if "quality_ok" in df.columns:
            ok = df["quality_ok"].astype(bool)
            dropped_quality = int((~ok).sum())
            df = df[ok]
        else:
            df = df[~df["saturated"]]
    if len(frames) == 0:
        raise CalibError("the session has no frames")
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    exp_ns = frames["exposure_ns"].to_numpy(np.int64)
    idx = df["frame"].to_numpy(np.int64)
    if np.any((idx < 0) | (idx >= ts.size)):
        raise CalibError(f"streak table names frames outside 0..{ts.size - 1}")
    if np.any(df["timestamp_ns"].to_numpy(np.int64) != ts[idx]):
        raise CalibError("streak table timestamps do not match the session's cam0/data.csv")
    t0_ns = int(ts[0])
    mid = None
    if {"mid_x", "mid_y"} <= set(df.columns):
        mid = df[["mid_x", "mid_y"]].to_numpy(float)
        if not np.all(np.isfinite(mid)):
            mid = None  # tables without usable midpoints support no inter-frame tracks
    return StreakSet(
        start=df[["start_x", "start_y"]].to_numpy(float),
        end=df[["end_x", "end_y"]].to_numpy(float),
        frame_t_s=(ts[idx] - t0_ns) * 1e-9,
        exposure_s=exp_ns[idx] * 1e-9,
        frame=idx,
        streak_id=df["streak_id"].to_numpy(np.int64),
        t0_s=t0_ns * 1e-9,
        centre=(
            np.stack([centre_points(c, centre_k) for c in df["centerline"]])
            if centre_k > 0 and len(df)
            else None
        ),
        mid=mid,
        dropped_quality=dropped_quality,
    )


def relative_gyro(gyro: GyroTrace, t0_s: float) -> GyroTrace:
    """The gyro trace with its times shifted by ``-t0_s`` (same origin as a StreakSet)."""
    return GyroTrace(gyro.t_s - t0_s, gyro.omega_radps, gyro.max_gap_s)


def covered_mask(
    streaks: StreakSet, gyro: GyroTrace, camera: Camera, shift_s: float, margin_s: float
) -> np.ndarray:
    """Streaks whose whole exposure (± ``margin_s`` of time-shift search) the gyro covers."""
    lo = streaks.frame_t_s + shift_s - margin_s
    hi = streaks.frame_t_s + camera.readout_s + streaks.exposure_s + shift_s + margin_s
    ok = np.zeros(len(streaks), dtype=bool)
    for f in np.unique(streaks.frame):
        sel = streaks.frame == f
        ok[sel] = gyro.covers(float(lo[sel].min()), float(hi[sel].max()))
    return ok


def holdout_mask(frames: np.ndarray, fraction: float) -> np.ndarray:
    """Deterministic frame-wise hold-out: every k-th distinct frame, ``k ≈ 1 / fraction``.

    >>> holdout_mask(np.array([0, 0, 1, 2, 3, 4]), 0.2).tolist()
    [False, False, False, False, False, True]
    """
    if not 0.0 <= fraction < 0.9:
        raise CalibError(f"hold-out fraction must be in [0, 0.9), got {fraction}")
    if fraction == 0.0:
        return np.zeros(frames.shape, dtype=bool)
    uniq = np.unique(frames)
    k = max(2, round(1.0 / fraction))
    held = uniq[(np.arange(uniq.size) % k) == k - 1]
    return np.isin(frames, held)
