"""Centre-line residuals: measured centre-line points against the predicted point track.

The time at which a dot passed a centre-line point is unknown (brightness along a streak is
not time), so a point is compared with the whole predicted track by a point-to-curve distance,
ICP-style: the track is the polyline of the measured start warped to ``n_sub + 1`` nodes
evenly spaced in time over the warp interval, each on the orientation grid of
:mod:`calib.grid` (linear between; the last node is the endpoint residual's); each measured
point is associated with its nearest segment at the current parameters (numpy), the
association is held fixed while the parameters move within one solver iteration, and the
residual is the signed perpendicular distance to that segment's line::

    r_c = ((B - A) × (c - A)) / sqrt(|B - A|² + ε²)          (pixels, one value per point)

with ``A``, ``B`` the segment's nodes and ``×`` the 2-D cross product. In the CasADi graph
(:class:`CentreGridEvaluator`) a point's residual warps the start to its segment's two nodes,
each with its own grid data, so it is differentiated exactly (association held) through the
same :mod:`blurtrack.geometry.kernels` functions as the endpoint residual.

Weights: each of a streak's ``K`` points gets ``CENTRE_WEIGHT / K``, so all of them together
weigh as much as one endpoint coordinate and a centre line never outweighs its endpoints.
Streaks shorter than :data:`MIN_CENTRE_LENGTH_PX` (no usable direction) or without a centre
line get weight zero.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import matmul3, transpose3
from calib.data import StreakSet
from calib.errors import CalibError
from calib.grid import GRID_STEP_S, N_BLOCK, N_DATA, GridEvaluator
from calib.gridops import mat3
from calib.params import N_THETA
from calib.problem import CA_OPS

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


class CentreGridEvaluator(GridEvaluator):
    """Endpoint and weighted centre-line residuals ``(N, 2 + K)`` and their Jacobians on the
    grid of :mod:`calib.grid` (interface of :class:`calib.grid.GridEvaluator`).

    The predicted track has ``n_sub + 1`` nodes at the fractions ``k / n_sub`` of the warp
    interval ``τ_a → τ_b`` (node ``n_sub`` is the endpoint residual's warped start), each
    ``Φ(τ_a)ᵀ Φ(τ_k)`` looked up on the grid: the gyro is sampled at explicit times, the
    grid's midpoints and the nodes. The point-to-track association is made at the parameters
    of each :meth:`evaluate` and held by :meth:`residual` until the next one (a fresh one for
    another streak set). In the SX function a centre point's residual warps the start to the
    two nodes of its segment with their own grid data (:meth:`GridEvaluator._block`), so the
    Jacobian is that of the grid model with the association held.
    """

    def __init__(
        self,
        gyro: GyroTrace,
        R0_cam_imu: np.ndarray,
        dist: tuple[float, ...],
        height: int,
        n_sub: int,
        centre_k: int,
        step_s: float = GRID_STEP_S,
    ) -> None:
        self.n_sub = int(n_sub)
        self.centre_k = int(centre_k)
        self.n_residuals = 2 + self.centre_k
        self.n_data = N_DATA + self.centre_k * _POINT_DATA + 1
        self._assoc: tuple[int, np.ndarray] | None = None
        super().__init__(gyro, R0_cam_imu, dist, height, step_s)

    def _residual_sx(self) -> ca.SX:
        d, k = self._d, self.centre_k
        cm = self._sx_common()
        sx, sy, ex, ey, ya, yb = (d[i] for i in range(6))
        u, v = self._warp_sx(cm, sx, sy, ya, yb, [d[6 + i] for i in range(N_BLOCK)])
        out = [u - ex, v - ey]
        factor = d[N_DATA + k * _POINT_DATA]
        for j in range(k):
            o = N_DATA + j * _POINT_DATA
            ends = []
            for e in range(2):  # the segment's nodes A, B: row fraction, then block
                b = o + e * (1 + N_BLOCK)
                blk = [d[b + 1 + i] for i in range(N_BLOCK)]
                ends.append(self._warp_sx(cm, sx, sy, ya, d[b], blk))
            (ax, ay), (bx, by) = ends
            c = o + 2 * (1 + N_BLOCK)
            out.append(factor * perpendicular(ax, ay, bx, by, d[c], d[c + 1], CA_OPS))
        return ca.vertcat(*out)

    def evaluate(
        self, theta: np.ndarray, streaks: StreakSet, free: tuple[int, ...] = tuple(range(N_THETA))
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(N, 2 + K)`` and Jacobian ``(N, 2 + K, N_THETA)``; associates the
        centre points with the track at ``theta``."""
        return self._evaluate_full(theta, streaks, free)

    def _centre(self, streaks: StreakSet) -> np.ndarray:
        if streaks.centre is None or streaks.centre.shape[1] != self.centre_k:
            raise CalibError(f"centre-line residuals need {self.centre_k} centre points per streak")
        return streaks.centre

    def _track(self, theta: np.ndarray, streaks: StreakSet, integrals: bool) -> dict[str, Any]:
        """The grid, the warp interval, ``Φ(τ_a)``, ``ω(τ_a)`` and the track nodes ``(N, S+1)``."""
        theta = np.asarray(theta, float)
        n, S = len(streaks), self.n_sub
        tau_a, tau_b = self._times(theta, streaks)
        grid = self._grid(theta, np.concatenate([tau_a, tau_b]), integrals)
        Pa, wa = self._at(grid, tau_a)
        T = self._node_times(tau_a, tau_b, np.tile(np.arange(S + 1), (n, 1)))
        Pk, _ = self._at(grid, T.reshape(-1))
        Pa_n = np.repeat(Pa, S + 1, axis=1)
        Q = matmul3(transpose3(mat3(Pa_n)), mat3(Pk))
        u, v = self._project(
            theta, np.repeat(streaks.start[:, 0], S + 1), np.repeat(streaks.start[:, 1], S + 1), Q
        )
        return {
            "grid": grid, "tau_a": tau_a, "tau_b": tau_b, "Pa": Pa, "wa": wa,
            "U": u.reshape(n, S + 1), "V": v.reshape(n, S + 1),
        }  # fmt: skip

    def _node_times(self, tau_a: np.ndarray, tau_b: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Times of nodes ``k`` ``(N, …)`` (node ``n_sub`` is ``τ_b`` exactly)."""
        f = k / self.n_sub
        T = tau_a[:, None] + f * (tau_b - tau_a)[:, None]
        return np.where(k == self.n_sub, tau_b[:, None], T)

    def residual(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """Residuals ``(N, 2 + K)``, centre lines under the held association."""
        tr = self._track(theta, streaks, False)
        U, V = tr["U"], tr["V"]
        centre = self._centre(streaks)
        if self._assoc is None or self._assoc[0] != len(streaks):
            self._assoc = (len(streaks), associate(U, V, centre))
        rc = centre_residual_np(U, V, centre, self._assoc[1], centre_factors(streaks))
        end = np.stack([U[:, -1] - streaks.end[:, 0], V[:, -1] - streaks.end[:, 1]], axis=1)
        return np.concatenate([end, rc], axis=1)

    def _data(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """``(n_data, N)``: the endpoint data of :meth:`GridEvaluator._data`, per centre point
        its segment's two nodes (row, :meth:`GridEvaluator._block`) and the point, then the
        streak's factor; associates the points with the track at ``theta``."""
        tr = self._track(theta, streaks, True)
        grid, tau_a, tau_b, Pa, wa = (tr[k] for k in ("grid", "tau_a", "tau_b", "Pa", "wa"))
        centre = self._centre(streaks)
        seg = associate(tr["U"], tr["V"], centre)
        self._assoc = (len(streaks), seg)
        rows = streaks.rows / self.height
        parts = [streaks.start.T, streaks.end.T, rows.T, self._block(grid, tau_a, Pa, wa, tau_b)]
        c = np.nan_to_num(centre)
        for j in range(self.centre_k):
            for node in (seg[:, j], seg[:, j] + 1):
                f = node / self.n_sub
                y = (1 - f) * rows[:, 0] + f * rows[:, 1]
                t = self._node_times(tau_a, tau_b, node[:, None])[:, 0]
                parts += [y[None], self._block(grid, tau_a, Pa, wa, t)]
            parts.append(c[:, j].T)
        parts.append(centre_factors(streaks)[None])
        return np.concatenate(parts, axis=0)


#: SX data of one centre point: its segment's two nodes (row fraction and block), the point.
_POINT_DATA = 2 * (1 + N_BLOCK) + 2
