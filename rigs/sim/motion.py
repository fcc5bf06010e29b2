"""The true, continuous camera motion of a simulated recording.

``ω_cam(t)`` is a C² cubic spline (rad/s, camera frame, camera clock) through a smooth,
uniformly sampled angular velocity: a band-passed stretch of a real shake trace or band-limited
random noise. The orientation ``R_c(t)`` (camera to world) is its exact integral, tabulated on a
0.1 ms grid by composing fourth-order Magnus exponential-map steps and refined between grid
points by one more such step; the world frame is the mean orientation over the recording, so
the dot grid stays centred in view. Dot positions always come from this motion, never from
sampled gyro data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from blurtrack.geometry.rotation import so3_exp
from rigs.sim.errors import SimError
from rigs.sim.shake import ShakeTrace, band_pass

#: Orientation table step (s), and most table entries (longer motions get longer steps).
TABLE_STEP_S = 1e-4
MAX_TABLE_STEPS = 2_000_000
#: Sample rate of the smooth ω before splining (Hz).
OMEGA_RATE_HZ = 1000.0


def cumulative_product(M: np.ndarray) -> np.ndarray:
    """Inclusive ordered products ``P[k] = M[0] @ M[1] @ ... @ M[k]`` of ``(N, 3, 3)``.

    A Hillis–Steele scan in ``log2(N)`` vectorised passes (a Python loop over 10^5 steps would
    dominate the simulator's start-up); the product order is preserved.

    >>> R = so3_exp(np.array([[0.0, 0.0, 0.1]] * 4))
    >>> P = cumulative_product(R)[-1]
    >>> round(float(np.arctan2(P[1, 0], P[0, 0])), 12)
    0.4
    """
    P = np.array(M, dtype=float, copy=True)
    shift = 1
    while shift < P.shape[0]:
        P[shift:] = P[:-shift] @ P[shift:]
        shift *= 2
    return P


class TrueMotion:
    """Continuous true camera motion over ``[t_begin_s, t_end_s]`` (camera clock).

    Args:
        t_s: ``(K,)`` strictly increasing knot times (s).
        omega_radps: ``(K, 3)`` camera-frame angular velocity at the knots (rad/s).
    """

    def __init__(
        self, t_s: np.ndarray, omega_radps: np.ndarray, step_s: float = TABLE_STEP_S
    ) -> None:
        t = np.asarray(t_s, dtype=float)
        w = np.asarray(omega_radps, dtype=float)
        if t.ndim != 1 or w.shape != (t.size, 3) or t.size < 4:
            raise SimError(
                f"motion needs >= 4 knots of t (K,) and omega (K, 3), got {t.shape}, {w.shape}"
            )
        if not (np.all(np.isfinite(w)) and np.all(np.diff(t) > 0)):
            raise SimError("motion knots must be finite with increasing times")
        self._spline = CubicSpline(t, w, axis=0)
        self.t_begin_s = float(t[0])
        self.t_end_s = float(t[-1])
        n = min(max(1, math.ceil((self.t_end_s - self.t_begin_s) / step_s)), MAX_TABLE_STEPS)
        self._h = (self.t_end_s - self.t_begin_s) / n
        self._grid = self.t_begin_s + self._h * np.arange(n + 1)
        steps = so3_exp(self._magnus(self._grid[:-1], np.full(n, self._h)))
        raw = np.concatenate([np.eye(3)[None], cumulative_product(steps)], axis=0)
        # World frame = chordal mean orientation, so the dots sit centred in the average view.
        u, _, vt = np.linalg.svd(raw.mean(axis=0))
        R_mean = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
        self._table = np.einsum("ij,njk->nik", R_mean.T, raw)

    def omega_cam_at(self, t_s: np.ndarray) -> np.ndarray:
        """True camera-frame angular velocity ``(M, 3)`` (rad/s) at camera times ``(M,)``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        self._check(t)
        return self._spline(t)

    def orientation(self, t_s: np.ndarray) -> np.ndarray:
        """True orientations ``R_c(t)`` (camera to world) ``(M, 3, 3)`` at camera times."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).reshape(-1)
        self._check(t)
        k = np.clip(
            np.floor((t - self.t_begin_s) / self._h).astype(np.int64), 0, self._grid.size - 2
        )
        step = so3_exp(self._magnus(self._grid[k], t - self._grid[k]))
        return self._table[k] @ step

    def _magnus(self, t0: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Rotation vectors ``(M, 3)`` of ``R_c(t0)ᵀ R_c(t0 + h)``: fourth-order Magnus step.

        With ω at the two Gauss points ``ω1, ω2``: ``h/2 (ω1 + ω2) + √3/12 h² (ω1 × ω2)``
        (``dR/dt = R [ω]×``); its error is O(h⁵) per step, 1e-12 rad per second of hand shake.
        """
        c = math.sqrt(3.0) / 6
        hh = h[:, None]
        w1 = self._spline(t0 + (0.5 - c) * h)
        w2 = self._spline(t0 + (0.5 + c) * h)
        return hh / 2 * (w1 + w2) + (math.sqrt(3.0) / 12) * hh * hh * np.cross(w1, w2)

    def _check(self, t: np.ndarray) -> None:
        if t.size and (t.min() < self.t_begin_s - 1e-9 or t.max() > self.t_end_s + 1e-9):
            raise SimError(
                f"true motion covers [{self.t_begin_s:.4f}, {self.t_end_s:.4f}] s, "
                f"asked for [{t.min():.4f}, {t.max():.4f}] s"
            )


def synthetic_omega(
    rng: np.random.Generator,
    duration_s: float,
    rms_radps: tuple[float, float, float],
    band_hz: tuple[float, float],
    rate_hz: float = OMEGA_RATE_HZ,
    pad_s: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Band-limited Gaussian random angular velocity: ``(t_s (M,), omega_radps (M, 3))``.

    White noise, band-passed (zero phase) and scaled so each axis has the given RMS over the
    returned span; times start at 0.
    """
    n_pad = round(pad_s * rate_hz)
    n = math.ceil(duration_s * rate_hz) + 1
    white = rng.standard_normal((n + 2 * n_pad, 3))
    w = band_pass(white, rate_hz, band_hz)[n_pad : n_pad + n]
    rms = np.sqrt(np.mean(w * w, axis=0))
    w = w * (np.asarray(rms_radps, dtype=float) / np.maximum(rms, 1e-300))
    return np.arange(n) / rate_hz, w


def shake_omega(
    trace: ShakeTrace,
    rng: np.random.Generator,
    duration_s: float,
    scale_range: tuple[float, float],
    band_hz: tuple[float, float],
    rate_hz: float = OMEGA_RATE_HZ,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """A seed-chosen, scaled stretch of a real shake trace as smooth ω.

    Returns ``(t_s (M,), omega_radps (M, 3), info)`` with times from 0 and ``info`` recording
    the chosen start (trace seconds) and scale.
    """
    margin = 1.0
    room = trace.duration_s - duration_s - 2 * margin
    if room <= 0:
        raise SimError(
            f"shake trace {trace.source} ({trace.duration_s:.1f} s) is too short for "
            f"{duration_s:.1f} s of motion"
        )
    start = float(trace.t_s[0] + margin + rng.uniform(0.0, room))
    scale = float(rng.uniform(*scale_range))
    t, w = trace.resampled(start, duration_s, rate_hz=rate_hz, band_hz=band_hz)
    return (
        t,
        w * scale,
        {
            "source": Path(trace.source).name,
            "start_s": start,
            "scale": scale,
            "dropouts_bridged": [
                list(g) for g in trace.gaps() if start - 1 < g[0] < start + duration_s + 1
            ],
        },
    )
