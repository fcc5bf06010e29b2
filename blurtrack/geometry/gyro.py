"""Gyroscope traces: samples on the IMU clock and their interpolation.

:class:`GyroTrace` interpolates ω piecewise linearly between its samples; the blur model first
resamples the measured trace through a cubic spline (:data:`GYRO_UPSAMPLE`, DESIGN: state how ω
is interpolated), so that fast shake is not under-reported between 200 Hz samples. The
trace refuses to answer for times it does not cover: outside its first and last sample, or
inside a gap longer than ``max_gap_s``.
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass, field

import numpy as np

from blurtrack.errors import CoverageError, GeometryError
from blurtrack.geometry.spline import MIN_KNOTS, resample_cubic

#: How the blur model interpolates ω between gyro samples: a not-a-knot cubic spline through
#: the samples, evaluated as linear interpolation of its ``GYRO_UPSAMPLE``-times denser
#: resampling (:meth:`GyroTrace.upsampled`). Prediction, synthesis, reports and the CasADi
#: calibration all use this one value.
GYRO_UPSAMPLE = 8
#: Queries :meth:`GyroTrace.omega_components` remembers (two threads of a fit, each with its
#: base and its current step).
RECENT_QUERIES = 4


@dataclass(frozen=True)
class GyroTrace:
    """Angular-velocity samples ``omega_radps (N, 3)`` at IMU-clock times ``t_s (N,)``.

    ``max_gap_s`` (default: 5 median sample intervals) is the longest interval between samples
    that still counts as covered.

    >>> tr = GyroTrace(np.array([0.0, 1.0]), np.array([[0.0, 0, 0], [2.0, 0, 0]]))
    >>> tr.omega_at(np.array([0.25]))[0].tolist()
    [0.5, 0.0, 0.0]
    """

    t_s: np.ndarray
    omega_radps: np.ndarray
    max_gap_s: float | None = None
    _gap_starts: np.ndarray = field(init=False, repr=False, compare=False)
    #: ``omega_radps``'s columns as contiguous arrays: ``np.interp`` copies a strided column
    #: on every call (80 000 samples of an upsampled 1 kHz trace: 10x the interpolation).
    _columns: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    #: Each column's slope between consecutive samples (:meth:`_interpolate`).
    _slopes: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    #: :meth:`upsampled` traces by factor: a spline through 10 s of 1 kHz gyro costs 0.3 s,
    #: and one calibration asks for the same resampling about ten times.
    _upsampled: dict[int, GyroTrace] = field(init=False, repr=False, compare=False)
    #: The last few :meth:`omega_components` queries and answers (read-only arrays): a
    #: finite-difference Jacobian asks again at the same times for every parameter that does
    #: not move them (focal lengths, bias, rotation: 10 of 12 in a natural fit with
    #: translation, where interpolation was 8 of 21 s).
    _recent: list[tuple[np.ndarray, tuple[np.ndarray, ...]]] = field(
        init=False, repr=False, compare=False
    )
    _lock: threading.Lock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t_s, dtype=float)
        w = np.ascontiguousarray(self.omega_radps, dtype=float)
        if t.ndim != 1 or w.shape != (t.size, 3):
            raise GeometryError(
                f"gyro trace needs t (N,) and omega (N, 3), got {t.shape} and {w.shape}"
            )
        if t.size < 2:
            raise CoverageError(f"gyro trace has {t.size} sample(s); at least 2 are needed")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))):
            raise GeometryError("gyro trace contains NaN or infinite values")
        if np.any(np.diff(t) <= 0):
            raise GeometryError("gyro timestamps must be strictly increasing")
        dt = np.diff(t)
        gap = float(self.max_gap_s) if self.max_gap_s is not None else 5.0 * float(np.median(dt))
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "omega_radps", w)
        object.__setattr__(self, "max_gap_s", gap)
        object.__setattr__(self, "_gap_starts", np.flatnonzero(dt > gap))
        object.__setattr__(self, "_columns", tuple(np.ascontiguousarray(w[:, k]) for k in range(3)))
        object.__setattr__(self, "_slopes", tuple(np.diff(c) / dt for c in self._columns))
        object.__setattr__(self, "_upsampled", {})
        object.__setattr__(self, "_recent", [])
        object.__setattr__(self, "_lock", threading.Lock())

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_s)))

    def omega_at(self, t_s: np.ndarray) -> np.ndarray:
        """ω (rad/s, IMU frame) at IMU-clock times ``t_s (M,)`` -> ``(M, 3)``, no coverage check."""
        return np.stack(self._interpolate(np.asarray(t_s, dtype=float)), axis=-1)

    def _interpolate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``np.interp(t, t_s, column)`` of the three columns, bit for bit (the same slope, the
        same ``slope * (t - t_j) + w_j``; the end samples' values outside, NaN for NaN), with
        one search of the sample times for all three (``np.interp`` searches once per column:
        the search is most of its cost on an upsampled trace)."""
        if t.ndim == 0:  # a single time: as a (1,) array, back to 0-d
            a, b, c = self._interpolate(t.reshape(1))
            return a.reshape(()), b.reshape(()), c.reshape(())
        xp = self.t_s
        j = np.searchsorted(xp, t, side="right") - 1
        jc = np.clip(j, 0, xp.size - 2)
        dx = t - xp[jc]
        before, after, nan = j < 0, j >= xp.size - 1, np.isnan(t)
        out = []
        for c, slope in zip(self._columns, self._slopes, strict=True):
            v = slope[jc] * dx + c[jc]
            v[before] = c[0]
            v[after] = c[-1]
            v[nan] = np.nan
            out.append(v)
        return out[0], out[1], out[2]

    def omega_components(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Like :meth:`omega_at` but as the ``(wx, wy, wz)`` tuple the model functions take."""
        t = np.asarray(t_s, dtype=float)
        with self._lock:
            for q, answer in self._recent:
                if q.shape == t.shape and np.array_equal(q, t):
                    return answer  # type: ignore[return-value]
        answer = self._interpolate(t)
        for a in answer:
            a.setflags(write=False)
        q = t.copy()
        q.setflags(write=False)
        with self._lock:
            self._recent.insert(0, (q, answer))
            del self._recent[RECENT_QUERIES:]
        return answer  # type: ignore[return-value]

    def covers(self, t0_s: float, t1_s: float) -> bool:
        try:
            self.check_coverage(t0_s, t1_s)
        except CoverageError:
            return False
        return True

    def check_coverage(self, t0_s: float, t1_s: float) -> None:
        """Raise :class:`CoverageError` unless samples cover ``[t0_s, t1_s]`` (IMU clock)."""
        lo, hi = min(t0_s, t1_s), max(t0_s, t1_s)
        if lo < self.t_s[0] or hi > self.t_s[-1]:
            raise CoverageError(
                f"gyro covers [{self.t_s[0]:.6f}, {self.t_s[-1]:.6f}] s but "
                f"[{lo:.6f}, {hi:.6f}] s is needed"
            )
        i = self._gap_starts
        bad = i[(self.t_s[i + 1] > lo) & (self.t_s[i] < hi)]
        if bad.size:
            k = int(bad[0])
            raise CoverageError(
                f"gyro gap of {1e3 * (self.t_s[k + 1] - self.t_s[k]):.1f} ms at "
                f"{self.t_s[k]:.6f} s inside the needed interval [{lo:.6f}, {hi:.6f}] s"
            )

    def segment(self, t0_s: float, t1_s: float) -> GyroTrace:
        """Samples within ``[t0_s, t1_s]`` plus one on each side where available."""
        i0 = max(int(np.searchsorted(self.t_s, t0_s, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(self.t_s, t1_s, side="left")) + 1, self.t_s.size)
        return GyroTrace(self.t_s[i0:i1], self.omega_radps[i0:i1], self.max_gap_s)

    def upsampled(self, factor: int) -> GyroTrace:
        """The trace resampled ``factor`` times more densely through cubic splines.

        Linear interpolation of point samples under-reports fast motion: between samples it
        cuts the curvature of ω, so the integrated angle of a component at frequency ``F`` is
        low by about ``(2π F Δt)² / 12`` (1.9 % at 15 Hz for a 200 Hz gyro). A cubic spline
        through the samples (not-a-knot, :mod:`blurtrack.geometry.spline`) is accurate to
        ``O(Δt⁴)``; linear interpolation of its dense resampling then stays within
        ``(2π F Δt / factor)² / 12``. The original samples are kept; gaps longer than
        ``max_gap_s`` are not bridged (each covered segment is splined on its own, segments
        under 4 samples stay linear).

        >>> tr = GyroTrace(np.arange(6.0), np.stack([np.arange(6.0) ** 2] * 3, axis=1))
        >>> round(float(tr.upsampled(2).omega_at(np.array([2.5]))[0, 0]), 9)
        6.25
        """
        k = int(factor)
        if k < 1:
            raise GeometryError(f"upsampling factor must be >= 1, got {factor}")
        if k == 1:
            return self
        if k not in self._upsampled:
            self._upsampled[k] = self._resampled(k)
        return self._upsampled[k]

    def _resampled(self, k: int) -> GyroTrace:
        """:meth:`upsampled` computed (``k >= 2``)."""
        bounds = np.concatenate([[0], self._gap_starts + 1, [self.t_s.size]])
        ts, ws = [], []
        for a, b in itertools.pairwise(bounds):
            t, w = self.t_s[a:b], self.omega_radps[a:b]
            if t.size < MIN_KNOTS:
                ts.append(t)
                ws.append(w)
                continue
            tt, ww = resample_cubic(t, w, k)
            ts.append(tt)
            ws.append(ww)
        return GyroTrace(np.concatenate(ts), np.concatenate(ws), self.max_gap_s)
