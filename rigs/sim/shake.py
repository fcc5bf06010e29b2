"""Real hand-shake gyroscope traces (GyroDeblurNet ``gyro_train.txt``) as a motion source.

The file holds tab-separated rows ``timestamp_ns wx wy wz`` (rad/s), a smartphone gyroscope at
about 210 Hz with the odd dropout. :func:`read_shake_trace` validates it;
:meth:`ShakeTrace.resampled` turns a stretch of it into a smooth, uniformly sampled angular
velocity: a C² cubic spline through the raw samples (which bridges dropouts smoothly), sampled
on a uniform grid and band-passed with a zero-phase Butterworth filter (scipy) to keep hand
shake and drop sensor noise and slow pans.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import butter, sosfiltfilt

from rigs.sim.errors import SimError

#: Where the project's data README puts the traces, relative to the repository's parent.
SHAKE_RELPATH = Path("shared") / "data" / "real" / "gyrodeblurnet-shake" / "gyro_train.txt"


def default_shake_path() -> Path:
    """``<repository>/../shared/data/real/gyrodeblurnet-shake/gyro_train.txt`` (may not exist)."""
    return Path(__file__).resolve().parents[3] / SHAKE_RELPATH


@dataclass(frozen=True)
class ShakeTrace:
    """Gyro samples ``omega_radps (N, 3)`` at strictly increasing times ``t_s (N,)``."""

    t_s: np.ndarray
    omega_radps: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=float)
        w = np.asarray(self.omega_radps, dtype=float)
        if t.ndim != 1 or w.shape != (t.size, 3) or t.size < 4:
            raise SimError(
                f"shake trace {self.source}: needs >= 4 samples of t (N,) and "
                f"omega (N, 3), got {t.shape} and {w.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))):
            raise SimError(f"shake trace {self.source}: NaN or infinite values")
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise SimError(f"shake trace {self.source}: timestamps not increasing at row {k + 2}")
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "omega_radps", w)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_s)))

    def gaps(self, factor: float = 3.0) -> list[tuple[float, float]]:
        """Dropouts: intervals between samples longer than ``factor`` median intervals."""
        dt = np.diff(self.t_s)
        idx = np.flatnonzero(dt > factor * np.median(dt))
        return [(float(self.t_s[i]), float(self.t_s[i + 1])) for i in idx]

    def resampled(
        self,
        t0_s: float,
        duration_s: float,
        rate_hz: float = 1000.0,
        band_hz: tuple[float, float] = (0.3, 15.0),
        pad_s: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Smooth ω on a uniform grid over ``[t0_s, t0_s + duration_s]`` (trace time).

        Returns ``(t_s (M,), omega_radps (M, 3))`` with times relative to ``t0_s``. The band-pass
        runs over ``pad_s`` more on each side (where the trace has it) to avoid edge effects.
        """
        lo = max(t0_s - pad_s, float(self.t_s[0]))
        hi = min(t0_s + duration_s + pad_s, float(self.t_s[-1]))
        if t0_s < self.t_s[0] or t0_s + duration_s > self.t_s[-1]:
            raise SimError(
                f"shake trace {self.source}: [{t0_s:.3f}, {t0_s + duration_s:.3f}] s "
                f"is outside the trace [{self.t_s[0]:.3f}, {self.t_s[-1]:.3f}] s"
            )
        sel = slice(
            max(int(np.searchsorted(self.t_s, lo)) - 2, 0), int(np.searchsorted(self.t_s, hi)) + 2
        )
        spline = CubicSpline(self.t_s[sel], self.omega_radps[sel], axis=0)
        n = int(np.ceil((hi - lo) * rate_hz)) + 1
        grid = lo + np.arange(n) / rate_hz
        w = band_pass(spline(grid), rate_hz, band_hz)
        keep = (grid >= t0_s - 2.0 / rate_hz) & (grid <= t0_s + duration_s + 2.0 / rate_hz)
        return grid[keep] - t0_s, w[keep]


def band_pass(omega: np.ndarray, rate_hz: float, band_hz: tuple[float, float]) -> np.ndarray:
    """Zero-phase 4th-order Butterworth band-pass of ``omega (M, 3)`` along time.

    A lower edge of 0 makes it a low-pass; an upper edge at or above Nyquist, a high-pass.
    """
    lo, hi = band_hz
    nyq = rate_hz / 2
    if hi >= nyq and lo <= 0:
        return omega.copy()
    if lo <= 0:
        sos = butter(4, hi, btype="lowpass", fs=rate_hz, output="sos")
    elif hi >= nyq:
        sos = butter(4, lo, btype="highpass", fs=rate_hz, output="sos")
    else:
        sos = butter(4, [lo, hi], btype="bandpass", fs=rate_hz, output="sos")
    if omega.shape[0] <= 3 * (2 * sos.shape[0] + 1):
        raise SimError(f"band-pass needs more than {omega.shape[0]} samples")
    return sosfiltfilt(sos, omega, axis=0)


def read_shake_trace(path: str | Path) -> ShakeTrace:
    """Read a GyroDeblurNet trace file through the project's one reader
    (:func:`blurtrack.io.shake.read_shake_trace`); its errors become :class:`SimError`."""
    from blurtrack.errors import BlurTrackError
    from blurtrack.io.shake import read_shake_trace as read_gyro_shake

    try:
        trace = read_gyro_shake(path)
    except BlurTrackError as exc:
        raise SimError(str(exc)) from None
    return ShakeTrace(trace.t_s, trace.omega_radps, source=str(path))
