"""Centre-line residuals: measured centre-line points against the predicted point track.

The time at which a dot passed a centre-line point is unknown (brightness along a streak is
not time), so a point is compared with the whole predicted track by a point-to-curve distance,
ICP-style: the track is the polyline of :func:`calib.problem.predicted_track` (the model's
sub-step nodes from the measured start over the warp interval, linear between); each measured
point is associated with its nearest segment at the current parameters (numpy), the
association is held fixed while the parameters move within one solver iteration, and the
residual is the signed perpendicular distance to that segment's line::

    r_c = ((B - A) × (c - A)) / sqrt(|B - A|² + ε²)          (pixels, one value per point)

with ``A``, ``B`` the segment's nodes and ``×`` the 2-D cross product. The CasADi graph selects
the segment by a one-hot data vector (the association), so the residual is differentiated
exactly through the same :mod:`blurtrack.geometry.kernels` functions as the endpoint residual.

Weights: each of a streak's ``K`` points gets ``CENTRE_WEIGHT / K``, so all of them together
weigh as much as one endpoint coordinate and a centre line never outweighs its endpoints.
Streaks shorter than :data:`MIN_CENTRE_LENGTH_PX` (no usable direction) or without a centre
line get weight zero.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.data import StreakSet

#: Interior centre-line points per streak.
CENTRE_POINTS = 4
#: Sum of the weights of one streak's centre-line residuals, in endpoint-coordinate units.
CENTRE_WEIGHT = 1.0
#: Shorter streaks carry no centre-line residual (their direction is noise).
MIN_CENTRE_LENGTH_PX = 3.0
#: Keeps the segment normal differentiable for a segment of zero length (px).
SEGMENT_EPS_PX = 1e-3


def centre_factors(streaks: StreakSet) -> np.ndarray:
    """``(N,)`` factor ``sqrt(weight)`` applied to every centre-line residual of a streak."""
    if streaks.centre is None:
        return np.zeros(len(streaks))
    k = streaks.centre.shape[1]
    ok = (streaks.length_px >= MIN_CENTRE_LENGTH_PX) & np.all(
        np.isfinite(streaks.centre), axis=(1, 2)
    )
    return np.where(ok, np.sqrt(CENTRE_WEIGHT / k), 0.0)


def associate(us: np.ndarray, vs: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Nearest track segment ``(N, K)`` (index ``0..n_sub-1``) of each centre point.

    Args:
        us, vs: ``(N, n_sub + 1)`` track nodes, px. centre: ``(N, K, 2)`` points, px (NaN rows
            get segment 0).
    """
    A = np.stack([us[:, :-1], vs[:, :-1]], axis=2)[:, None]  # (N, 1, S, 2)
    D = np.stack([np.diff(us, axis=1), np.diff(vs, axis=1)], axis=2)[:, None]
    P = np.nan_to_num(centre)[:, :, None, :]  # (N, K, 1, 2)
    dd = np.sum(D * D, axis=3)
    t = np.clip(np.sum((P - A) * D, axis=3) / np.maximum(dd, 1e-300), 0.0, 1.0)
    dist2 = np.sum((A + t[..., None] * D - P) ** 2, axis=3)  # (N, K, S)
    return np.argmin(dist2, axis=2)


def perpendicular(ax: Any, ay: Any, bx: Any, by: Any, px: Any, py: Any, ops: Any) -> Any:
    """Signed distance (px) of ``p`` from the line through ``a`` and ``b`` (batched)."""
    dx, dy = bx - ax, by - ay
    return (dx * (py - ay) - dy * (px - ax)) / ops.sqrt(dx * dx + dy * dy + SEGMENT_EPS_PX**2)


def centre_residual_np(
    us: np.ndarray, vs: np.ndarray, centre: np.ndarray, seg: np.ndarray, factor: np.ndarray
) -> np.ndarray:
    """Weighted centre-line residuals ``(N, K)`` for a fixed association ``seg`` ``(N, K)``."""
    from blurtrack.geometry.kernels import NUMPY_OPS

    rows = np.arange(us.shape[0])[:, None]
    c = np.nan_to_num(centre)
    r = perpendicular(
        us[rows, seg],
        vs[rows, seg],
        us[rows, seg + 1],
        vs[rows, seg + 1],
        c[..., 0],
        c[..., 1],
        NUMPY_OPS,
    )
    return r * factor[:, None]


def centre_residual_sx(
    us: list[Any], vs: list[Any], data: Any, base: int, k: int, ops: Any
) -> list[Any]:
    """The same residuals in a per-streak CasADi graph.

    ``data[base:]`` holds, per point, ``x, y`` and a one-hot vector over the ``n_sub``
    segments, then the streak's factor (layout of :func:`centre_data`).
    """
    n_sub = len(us) - 1
    width = 2 + n_sub
    factor = data[base + k * width]
    out = []
    for j in range(k):
        o = base + j * width
        hot = [data[o + 2 + s] for s in range(n_sub)]
        ax = sum(h * us[s] for s, h in enumerate(hot))
        ay = sum(h * vs[s] for s, h in enumerate(hot))
        bx = sum(h * us[s + 1] for s, h in enumerate(hot))
        by = sum(h * vs[s + 1] for s, h in enumerate(hot))
        out.append(factor * perpendicular(ax, ay, bx, by, data[o], data[o + 1], ops))
    return out


def centre_data(centre: np.ndarray, seg: np.ndarray, factor: np.ndarray, n_sub: int) -> np.ndarray:
    """``(N, K (2 + n_sub) + 1)`` data of :func:`centre_residual_sx`."""
    n, k, _ = centre.shape
    hot = np.zeros((n, k, n_sub))
    np.put_along_axis(hot, seg[..., None], 1.0, axis=2)
    per = np.concatenate([np.nan_to_num(centre), hot], axis=2).reshape(n, -1)
    return np.concatenate([per, factor[:, None]], axis=1)
