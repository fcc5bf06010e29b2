"""Exact residual Jacobians by CasADi, per streak in SX, mapped over all streaks.

The gyro enters the model only through ``omega_imu_at(t)`` at the integration sub-step times,
and the interpolated gyro is piecewise linear in ``t``. So at the current parameters each call
can be replaced by its exact local form ``ω_k + ω'_k (t − t_k)``, with ``t_k`` the sub-step time
the model asks for at the current parameters and ``ω_k``, ``ω'_k`` the interpolated rate and
its slope there (numbers computed by a numpy pass of the same model that records the times).
Value and first derivative with respect to every parameter are then exactly those of the
``ca.interpolant(..., 'linear')`` form (:meth:`ResidualModel.casadi_functions`; a test checks
the equality), but the graph is plain arithmetic: one scalar SX function per streak, its
Jacobian by ``ca.jacobian`` with common subexpressions shared, ``Function.map`` over streaks.
This is many times faster than calling the interpolant per element inside an MX graph.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from blurtrack.geometry.kernels import NUMPY_OPS
from calib.centreline import (
    associate,
    centre_data,
    centre_factors,
    centre_residual_np,
    centre_residual_sx,
)
from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import N_THETA
from calib.problem import CA_OPS, N_COLS, ResidualModel, endpoint_residual, predicted_track


def _slopes(t_grid: np.ndarray, w_grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Slope ``(…, 3)`` of the linear interpolant of ``w_grid`` at times ``t`` (…)."""
    i = np.clip(np.searchsorted(t_grid, t, side="right") - 1, 0, t_grid.size - 2)
    return (w_grid[i + 1] - w_grid[i]) / (t_grid[i + 1] - t_grid[i])[..., None]


class JacobianEvaluator:
    """Residuals ``(N, m)`` and Jacobians ``(N, m, N_THETA)`` of streak sets under one model
    (columns of fixed parameters are zero). ``m = 2`` (endpoint) or, with ``centre_k > 0``,
    ``2 + centre_k``: the weighted centre-line residuals of :mod:`calib.centreline`, whose
    point-to-track association is made at the parameters of each :meth:`evaluate` and held by
    :meth:`residual` until the next one."""

    def __init__(self, model: ResidualModel, centre_k: int = 0) -> None:
        self.model = model
        self.centre_k = centre_k
        ns = model.n_sub
        n_local = N_COLS + 7 * ns
        self._th = ca.SX.sym("theta", N_THETA)
        self._d = ca.SX.sym("d", n_local + (centre_k * (2 + ns) + 1 if centre_k else 0))
        d = self._d
        calls = [0]

        def omega_local(t: Any) -> tuple:
            k = calls[0]
            calls[0] += 1
            if k >= ns:
                raise CalibError("the model asked the gyro more often than its sub-steps")
            base = N_COLS + 7 * k
            return tuple(d[base + 1 + a] + d[base + 4 + a] * (t - d[base]) for a in range(3))

        th = [self._th[i] for i in range(N_THETA)]
        cols = [d[j] for j in range(N_COLS)]
        if centre_k:
            us, vs = predicted_track(
                th, cols, omega_local, model.R0_cam_imu, model.dist, model.height, ns, CA_OPS
            )
            res = [
                us[-1] - d[2],
                vs[-1] - d[3],
                *centre_residual_sx(us, vs, d, n_local, centre_k, CA_OPS),
            ]
        else:
            res = list(
                endpoint_residual(
                    th, cols, omega_local, model.R0_cam_imu, model.dist, model.height, ns, CA_OPS
                )
            )
        if calls[0] != ns:
            raise CalibError(f"the model asked the gyro {calls[0]} times, expected {ns}")
        self._r = ca.vertcat(*res)
        self._m = len(res)
        self._funcs: dict[tuple[int, ...], ca.Function] = {}
        self._maps: dict[tuple[tuple[int, ...], int], ca.Function] = {}
        self._assoc: tuple[int, np.ndarray] | None = None

    @property
    def n_residuals(self) -> int:
        """Residual values per streak (2 + centre-line points)."""
        return self._m

    def _track(
        self, theta: np.ndarray, streaks: StreakSet, gyro_at: Any
    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        m = self.model
        return predicted_track(
            list(np.asarray(theta, float)),
            list(m.data_matrix(streaks).T),
            gyro_at,
            m.R0_cam_imu,
            m.dist,
            m.height,
            m.n_sub,
            NUMPY_OPS,
        )

    def _local_data(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """``(N_COLS + 7 n_sub [+ centre data], N)``: streak columns, then per sub-step ``t_k, ω_k
        (3), ω'_k (3)``, then (centre lines) the association of :mod:`calib.centreline`."""
        g = self.model.gyro
        times: list[np.ndarray] = []

        def recorder(t: np.ndarray) -> tuple:
            times.append(np.asarray(t, dtype=float))
            return g.omega_components(t)

        cols = self.model.data_matrix(streaks)
        if self.centre_k:
            us, vs = self._track(theta, streaks, recorder)
        else:
            endpoint_residual(
                list(np.asarray(theta, float)),
                list(cols.T),
                recorder,
                self.model.R0_cam_imu,
                self.model.dist,
                self.model.height,
                self.model.n_sub,
                NUMPY_OPS,
            )
        T = np.stack(times, axis=1)  # (N, n_sub)
        W = g.omega_at(T.reshape(-1)).reshape(*T.shape, 3)
        S = _slopes(g.t_s, g.omega_radps, T)
        local = np.concatenate([T[..., None], W, S], axis=2).reshape(T.shape[0], -1)
        parts = [cols, local]
        if self.centre_k:
            centre = self._centre(streaks)
            seg = associate(np.stack(us, axis=1), np.stack(vs, axis=1), centre)
            self._assoc = (len(streaks), seg)
            parts.append(centre_data(centre, seg, centre_factors(streaks), self.model.n_sub))
        return np.concatenate(parts, axis=1).T

    def _centre(self, streaks: StreakSet) -> np.ndarray:
        if streaks.centre is None or streaks.centre.shape[1] != self.centre_k:
            raise CalibError(f"centre-line residuals need {self.centre_k} centre points per streak")
        return streaks.centre

    def residual(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """Residuals ``(N, m)`` by numpy, centre lines under the last :meth:`evaluate`'s
        association (a fresh one if that was of another streak set)."""
        if not self.centre_k:
            return self.model.residual_np(theta, streaks)
        us, vs = self._track(theta, streaks, self.model.gyro.omega_components)
        U, V = np.stack(us, axis=1), np.stack(vs, axis=1)
        centre = self._centre(streaks)
        if self._assoc is None or self._assoc[0] != len(streaks):
            self._assoc = (len(streaks), associate(U, V, centre))
        rc = centre_residual_np(U, V, centre, self._assoc[1], centre_factors(streaks))
        return np.concatenate(
            [np.stack([U[:, -1] - streaks.end[:, 0], V[:, -1] - streaks.end[:, 1]], axis=1), rc],
            axis=1,
        )

    def _map(self, free: tuple[int, ...], n: int) -> ca.Function:
        if free not in self._funcs:
            J = ca.jacobian(self._r, ca.vertcat(*[self._th[i] for i in free]))
            self._funcs[free] = ca.Function("calib_jac", [self._th, self._d], [self._r, J])
        key = (free, n)
        if key not in self._maps:
            self._maps[key] = self._funcs[free].map(n, "serial")
        return self._maps[key]

    def evaluate(
        self, theta: np.ndarray, streaks: StreakSet, free: tuple[int, ...] = tuple(range(N_THETA))
    ) -> tuple[np.ndarray, np.ndarray]:
        n = len(streaks)
        data = self._local_data(theta, streaks)
        th = np.tile(np.asarray(theta, float)[:, None], (1, n))
        r_out, j_out = self._map(tuple(free), n)(th, data)
        p, m = len(free), self._m
        r = np.asarray(r_out).T  # (N, m)
        J = np.asarray(j_out).reshape(m, n, p)  # columns: one (m, p) block per streak
        full = np.zeros((n, m, N_THETA))
        full[:, :, list(free)] = J.transpose(1, 0, 2)
        return r, full
