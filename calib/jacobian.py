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

from blurtrack.model import NUMPY_OPS
from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import N_THETA
from calib.problem import CA_OPS, ResidualModel, endpoint_residual


def _slopes(t_grid: np.ndarray, w_grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Slope ``(…, 3)`` of the linear interpolant of ``w_grid`` at times ``t`` (…)."""
    i = np.clip(np.searchsorted(t_grid, t, side="right") - 1, 0, t_grid.size - 2)
    return (w_grid[i + 1] - w_grid[i]) / (t_grid[i + 1] - t_grid[i])[..., None]


class JacobianEvaluator:
    """Residuals ``(N, 2)`` and Jacobians ``(N, 2, N_THETA)`` of streak sets under one model
    (columns of fixed parameters are zero)."""

    def __init__(self, model: ResidualModel) -> None:
        self.model = model
        ns = model.n_sub
        self._th = ca.SX.sym("theta", N_THETA)
        self._d = ca.SX.sym("d", 6 + 7 * ns)
        d = self._d
        calls = [0]

        def omega_local(t: Any) -> tuple:
            k = calls[0]
            calls[0] += 1
            if k >= ns:
                raise CalibError("the model asked the gyro more often than its sub-steps")
            base = 6 + 7 * k
            return tuple(d[base + 1 + a] + d[base + 4 + a] * (t - d[base]) for a in range(3))

        rx, ry = endpoint_residual([self._th[i] for i in range(N_THETA)],
                                   [d[j] for j in range(6)], omega_local, model.R0_cam_imu,
                                   model.dist, model.height, ns, CA_OPS)
        if calls[0] != ns:
            raise CalibError(f"the model asked the gyro {calls[0]} times, expected {ns}")
        self._r = ca.vertcat(rx, ry)
        self._funcs: dict[tuple[int, ...], ca.Function] = {}
        self._maps: dict[tuple[tuple[int, ...], int], ca.Function] = {}

    def _local_data(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """``(6 + 7 n_sub, N)``: streak columns, then per sub-step ``t_k, ω_k (3), ω'_k (3)``."""
        g = self.model.gyro
        times: list[np.ndarray] = []

        def recorder(t: np.ndarray) -> tuple:
            times.append(np.asarray(t, dtype=float))
            return g.omega_components(t)

        cols = self.model.data_matrix(streaks)
        endpoint_residual(list(np.asarray(theta, float)), list(cols.T), recorder,
                          self.model.R0_cam_imu, self.model.dist, self.model.height,
                          self.model.n_sub, NUMPY_OPS)
        T = np.stack(times, axis=1)  # (N, n_sub)
        W = g.omega_at(T.reshape(-1)).reshape(*T.shape, 3)
        S = _slopes(g.t_s, g.omega_radps, T)
        local = np.concatenate([T[..., None], W, S], axis=2).reshape(T.shape[0], -1)
        return np.concatenate([cols, local], axis=1).T

    def _map(self, free: tuple[int, ...], n: int) -> ca.Function:
        if free not in self._funcs:
            J = ca.jacobian(self._r, ca.vertcat(*[self._th[i] for i in free]))
            self._funcs[free] = ca.Function("calib_jac", [self._th, self._d], [self._r, J])
        key = (free, n)
        if key not in self._maps:
            self._maps[key] = self._funcs[free].map(n, "serial")
        return self._maps[key]

    def evaluate(self, theta: np.ndarray, streaks: StreakSet,
                 free: tuple[int, ...] = tuple(range(N_THETA))) -> tuple[np.ndarray, np.ndarray]:
        n = len(streaks)
        data = self._local_data(theta, streaks)
        th = np.tile(np.asarray(theta, float)[:, None], (1, n))
        r_out, j_out = self._map(tuple(free), n)(th, data)
        p = len(free)
        r = np.asarray(r_out).T  # (N, 2)
        J = np.asarray(j_out).reshape(2, n, p)  # columns: one (2, p) block per streak
        full = np.zeros((n, 2, N_THETA))
        full[:, :, list(free)] = J.transpose(1, 0, 2)
        return r, full
