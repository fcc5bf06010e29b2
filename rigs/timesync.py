"""Map device time onto host time from the arrival times of samples.

Every sample arrives at host time ``host = offset + (1 + drift) * dev + latency`` with a latency
that is never below the transport's minimum and is often far above it (USB polling, scheduler
jitter, bursts). Least squares would fit the mean latency, biased by every hiccup; we fit the
*lower envelope* of ``delay = host - dev`` over device time instead: the line that lies below
every point and is as high as possible on average, i.e. the linear programme

    maximise  sum_i (a + b x_i)   subject to   a + b x_i <= y_i  for all i,

whose optimum is the edge of the lower convex hull of the points (x_i, y_i) above the mean of x.
The hull is computed with Andrew's monotone chain, O(N log N), which for 10^6 samples is far
faster than a general LP solver; that is why it is written by hand. The slope ``b`` is the
relative clock drift.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from rigs.errors import TimeSyncError


@dataclass(frozen=True)
class ClockMap:
    """Affine device-to-host map fitted by :func:`fit_clock_map`.

    ``host_ns = dev_ns + ref_delay_ns + round(1e9 * (intercept_s + drift * (dev_ns - ref_dev_ns)
    / 1e9))`` where ``drift`` is dimensionless (1e-4 = 100 ppm).
    """

    ref_dev_ns: int
    ref_delay_ns: int
    intercept_s: float
    drift: float
    min_latency_s: float
    n_points: int
    delay_above_envelope_median_s: float
    delay_above_envelope_p99_s: float

    @property
    def drift_ppm(self) -> float:
        return self.drift * 1e6

    def to_host_ns(self, dev_ns: np.ndarray) -> np.ndarray:
        """Host times (int64 ns) of device times ``dev_ns`` (N,) int64 ns."""
        dev_ns = np.asarray(dev_ns, dtype=np.int64)
        x_s = (dev_ns - self.ref_dev_ns).astype(np.float64) * 1e-9
        corr_ns = np.rint((self.intercept_s - self.min_latency_s + self.drift * x_s) * 1e9)
        return dev_ns + self.ref_delay_ns + corr_ns.astype(np.int64)

    def as_dict(self) -> dict[str, float | int]:
        return {
            "drift_ppm": self.drift_ppm,
            "min_latency_s": self.min_latency_s,
            "n_points": self.n_points,
            "delay_above_envelope_median_s": self.delay_above_envelope_median_s,
            "delay_above_envelope_p99_s": self.delay_above_envelope_p99_s,
        }


def lower_hull(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the lower convex hull of points sorted by x (ties: lowest y kept).

    >>> lower_hull(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.0, -1.0, 1.0, 0.0])).tolist()
    [0, 1, 3]
    """
    xs, ys = np.asarray(x, dtype=float).tolist(), np.asarray(y, dtype=float).tolist()
    hull: list[int] = []
    for i in range(len(xs)):
        while len(hull) >= 2:
            o, a = hull[-2], hull[-1]
            cross = (xs[a] - xs[o]) * (ys[i] - ys[o]) - (ys[a] - ys[o]) * (xs[i] - xs[o])
            if cross <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return np.asarray(hull, dtype=np.int64)


def fit_clock_map(dev_ns: np.ndarray, host_ns: np.ndarray, min_latency_s: float = 0.0) -> ClockMap:
    """Fit the lower envelope of host-minus-device delay against device time.

    dev_ns: (N,) int64 device times of samples (unwrapped), ns. host_ns: (N,) int64 host times
    at which they were read, ns. ``min_latency_s`` is a known transport minimum (e.g. the time
    one frame takes on the wire) subtracted from the envelope, so that mapped times estimate
    the sampling instant rather than the earliest arrival.
    """
    dev_ns = np.asarray(dev_ns, dtype=np.int64).ravel()
    host_ns = np.asarray(host_ns, dtype=np.int64).ravel()
    if dev_ns.shape != host_ns.shape:
        raise TimeSyncError("device and host time arrays differ in length")
    if not np.isfinite(min_latency_s) or min_latency_s < 0:
        raise TimeSyncError("min_latency_s must be a finite non-negative number")
    if dev_ns.size < 2:
        raise TimeSyncError(f"{dev_ns.size} samples are too few to fit a clock map")
    order = np.argsort(dev_ns, kind="stable")
    dev_ns, host_ns = dev_ns[order], host_ns[order]
    delay_ns = host_ns - dev_ns
    ref_dev, ref_delay = int(dev_ns[0]), int(delay_ns.min())
    x = (dev_ns - ref_dev).astype(np.float64) * 1e-9
    y = (delay_ns - ref_delay).astype(np.float64) * 1e-9
    # keep the lowest delay per distinct device time, so that the hull sees distinct x
    keep = np.ones(x.size, dtype=bool)
    keep[:-1] = x[1:] != x[:-1]
    if np.count_nonzero(keep) < 2:
        raise TimeSyncError("all samples share one device time; cannot fit a clock map")
    if not np.all(keep):
        starts = np.flatnonzero(np.r_[True, x[1:] != x[:-1]])
        y_u = np.minimum.reduceat(y, starts)
        x_u = x[starts]
    else:
        x_u, y_u = x, y
    hull = lower_hull(x_u, y_u)
    x_mean = float(x.mean())
    pos = int(np.searchsorted(x_u[hull], x_mean, side="right"))
    pos = min(max(pos, 1), hull.size - 1)
    i, j = hull[pos - 1], hull[pos]
    slope = float((y_u[j] - y_u[i]) / (x_u[j] - x_u[i]))
    intercept = float(y_u[i] - slope * x_u[i])
    above = y - (intercept + slope * x)
    if not np.all(np.isfinite(above)):
        raise TimeSyncError("non-finite delays; check the recorded timestamps")
    return ClockMap(
        ref_dev_ns=ref_dev,
        ref_delay_ns=ref_delay,
        intercept_s=intercept,
        drift=slope,
        min_latency_s=float(min_latency_s),
        n_points=int(dev_ns.size),
        delay_above_envelope_median_s=float(np.median(above)),
        delay_above_envelope_p99_s=float(np.percentile(above, 99)),
    )


@dataclass(frozen=True)
class PiecewiseClockMap:
    """Device-to-host map for long recordings whose drift changes (temperature): one
    lower-envelope line per window, joined by linear interpolation of the host-minus-device
    delay between window centres; outside the first and last centres, the end windows' lines.
    """

    windows: tuple[ClockMap, ...]
    centres_dev_ns: np.ndarray  # (K,) int64, increasing

    @property
    def drift_ppm(self) -> float:
        """Mean drift over the recording (ppm)."""
        return float(np.mean([w.drift_ppm for w in self.windows]))

    def to_host_ns(self, dev_ns: np.ndarray) -> np.ndarray:
        """Host times (int64 ns) of device times ``dev_ns`` (N,) int64 ns."""
        dev_ns = np.asarray(dev_ns, dtype=np.int64)
        if len(self.windows) == 1:
            return self.windows[0].to_host_ns(dev_ns)
        c = self.centres_dev_ns
        delay_c = np.array(
            [int(w.to_host_ns(c[k : k + 1])[0] - c[k]) for k, w in enumerate(self.windows)],
            dtype=np.int64,
        )
        # interpolate relative to the first centre's delay, so float64 keeps ns resolution
        rel = np.interp(
            (dev_ns - c[0]).astype(np.float64),
            (c - c[0]).astype(np.float64),
            (delay_c - delay_c[0]).astype(np.float64),
        )
        out = dev_ns + delay_c[0] + np.rint(rel).astype(np.int64)
        lo, hi = dev_ns < c[0], dev_ns > c[-1]
        out[lo] = self.windows[0].to_host_ns(dev_ns[lo])
        out[hi] = self.windows[-1].to_host_ns(dev_ns[hi])
        return out

    def as_dict(self) -> dict[str, float | int]:
        drifts = [w.drift_ppm for w in self.windows]
        return {
            "windows": len(self.windows),
            "drift_ppm": self.drift_ppm,
            "drift_ppm_min": float(min(drifts)),
            "drift_ppm_max": float(max(drifts)),
            "min_latency_s": self.windows[0].min_latency_s,
            "n_points": int(sum(w.n_points for w in self.windows)),
            "delay_above_envelope_median_s": float(
                np.median([w.delay_above_envelope_median_s for w in self.windows])
            ),
            "delay_above_envelope_p99_s": float(
                max(w.delay_above_envelope_p99_s for w in self.windows)
            ),
        }


def fit_clock_map_windowed(
    dev_ns: np.ndarray,
    host_ns: np.ndarray,
    min_latency_s: float = 0.0,
    window_s: float = 60.0,
) -> PiecewiseClockMap:
    """:func:`fit_clock_map` per ``window_s`` of device time (one window for short recordings;
    a last window shorter than half a window joins the previous one)."""
    if not window_s > 0:
        raise TimeSyncError("window_s must be positive")
    dev_ns = np.asarray(dev_ns, dtype=np.int64).ravel()
    host_ns = np.asarray(host_ns, dtype=np.int64).ravel()
    if dev_ns.shape != host_ns.shape:
        raise TimeSyncError("device and host time arrays differ in length")
    if dev_ns.size < 2:
        raise TimeSyncError(f"{dev_ns.size} samples are too few to fit a clock map")
    order = np.argsort(dev_ns, kind="stable")
    dev_ns, host_ns = dev_ns[order], host_ns[order]
    width = round(window_s * 1e9)
    span = int(dev_ns[-1] - dev_ns[0])
    n_win = max(1, round(span / width))
    edges = dev_ns[0] + np.round(np.linspace(0, span, n_win + 1)).astype(np.int64)
    idx = np.searchsorted(dev_ns, edges[1:-1], side="left")
    bounds = [0, *idx.tolist(), dev_ns.size]
    windows, centres = [], []
    for a, b in itertools.pairwise(bounds):
        windows.append(fit_clock_map(dev_ns[a:b], host_ns[a:b], min_latency_s))
        centres.append((int(dev_ns[a]) + int(dev_ns[b - 1])) // 2)
    return PiecewiseClockMap(tuple(windows), np.asarray(centres, dtype=np.int64))
