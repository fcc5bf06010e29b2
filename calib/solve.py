"""Robust Levenberg–Marquardt on CasADi's exact Jacobian (Gauss–Newton Hessian ``JᵀWJ``).

The residual graph is built once for a chunk of :data:`CHUNK` streaks and mapped over the
chunks (``Function.map``), so the graph stays small however many streaks there are. The
Jacobian comes from forward directional derivatives (``ca.jtimes``) of that graph, one per
free parameter.
The robust loss is pseudo-Huber on each streak's endpoint error ``ρ = |r|``:
``δ² (sqrt(1 + (ρ/δ)²) − 1)``, minimised by iteratively reweighted Gauss–Newton with weights
``1 / sqrt(1 + (ρ/δ)²)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import N_THETA, THETA_NAMES
from calib.problem import CA_OPS, ResidualModel, endpoint_residual

#: Streaks per CasADi graph chunk.
CHUNK = 200


class JacobianEvaluator:
    """Residuals ``(N, 2)`` and Jacobians ``(N, 2, N_THETA)`` of streak sets under one model.

    The chunk graph is built once per model; the forward-mode Jacobian once per set of free
    parameters (only those columns are computed, the others are zero); evaluating another
    streak set only maps it over a different number of chunks.
    """

    def __init__(self, model: ResidualModel) -> None:
        self.model = model
        self._theta = ca.MX.sym("theta", N_THETA)
        self._D = ca.MX.sym("D", CHUNK, 6)
        interp = [ca.interpolant(f"omega_{k}", "linear", [model.gyro.t_s],
                                 model.gyro.omega_radps[:, k]) for k in range(3)]
        rx, ry = endpoint_residual([self._theta[i] for i in range(N_THETA)],
                                   [self._D[:, j] for j in range(6)],
                                   lambda t: tuple(f(t) for f in interp), model.R0_cam_imu,
                                   model.dist, model.height, model.n_sub, CA_OPS)
        self._r = ca.vertcat(rx, ry)
        self._maps: dict[tuple[tuple[int, ...], int], ca.Function] = {}
        self._funcs: dict[tuple[int, ...], ca.Function] = {}

    def _map(self, free: tuple[int, ...], n_chunks: int) -> ca.Function:
        if free not in self._funcs:
            seeds = ca.DM(np.eye(N_THETA)[:, list(free)])
            self._funcs[free] = ca.Function("calib_jac", [self._theta, self._D],
                                            [self._r, ca.jtimes(self._r, self._theta, seeds)])
        key = (free, n_chunks)
        if key not in self._maps:
            self._maps[key] = self._funcs[free].map(n_chunks, "serial")
        return self._maps[key]

    def evaluate(self, theta: np.ndarray, streaks: StreakSet,
                 free: tuple[int, ...] = tuple(range(N_THETA))) -> tuple[np.ndarray, np.ndarray]:
        n = len(streaks)
        n_chunks = max(1, -(-n // CHUNK))
        D = self.model.data_matrix(streaks)
        pad = n_chunks * CHUNK - n
        if pad:
            D = np.vstack([D, np.repeat(D[-1:], pad, axis=0)])
        D = np.hstack([D[i * CHUNK:(i + 1) * CHUNK] for i in range(n_chunks)])
        th = np.tile(np.asarray(theta, float)[:, None], (1, n_chunks))
        r_out, j_out = self._map(tuple(free), n_chunks)(th, D)
        p = len(free)
        r = np.asarray(r_out)  # (2*CHUNK, n_chunks)
        J = np.asarray(j_out).reshape(2 * CHUNK, n_chunks, p)
        r = np.stack([r[:CHUNK].T.reshape(-1), r[CHUNK:].T.reshape(-1)], axis=1)
        Jx = J[:CHUNK].transpose(1, 0, 2).reshape(-1, p)
        Jy = J[CHUNK:].transpose(1, 0, 2).reshape(-1, p)
        full = np.zeros((n, 2, N_THETA))
        full[:, :, list(free)] = np.stack([Jx, Jy], axis=1)[:n]
        return r[:n], full


def pseudo_huber(rho: np.ndarray, delta: float) -> np.ndarray:
    """Pseudo-Huber loss of endpoint errors ``rho`` (px) with scale ``delta`` (px)."""
    return delta**2 * (np.sqrt(1.0 + (rho / delta) ** 2) - 1.0)


def huber_weights(rho: np.ndarray, delta: float) -> np.ndarray:
    return 1.0 / np.sqrt(1.0 + (rho / delta) ** 2)


@dataclass(frozen=True)
class LMResult:
    theta: np.ndarray
    iterations: int
    converged: bool
    cost: float
    residual: np.ndarray  # (N, 2)
    jacobian: np.ndarray  # (N, 2, N_THETA), zero in the columns of fixed parameters
    weights: np.ndarray  # (N,)


def levenberg_marquardt(
    ev: JacobianEvaluator, streaks: StreakSet, theta0: np.ndarray, free: tuple[int, ...],
    delta_px: float, max_iter: int = 30, step_tol: float = 1e-6, rel_tol: float = 1e-8,
    lam0: float = 1e-3,
) -> LMResult:
    """Minimise the pseudo-Huber endpoint cost over the ``free`` entries of theta.

    Convergence: every parameter step, scaled by ``sqrt`` of its Gauss–Newton information,
    below ``step_tol`` (pixels of residual; a step below a few percent of the residual sigma
    is far below the parameter's own 1-sigma), a relative cost decrease below ``rel_tol``,
    or no further cost decrease.
    """
    if not free:
        raise CalibError("no parameter left to fit")
    model = ev.model
    theta = np.asarray(theta0, float).copy()
    fr = np.asarray(free)
    lam = lam0
    r, J = ev.evaluate(theta, streaks, tuple(free))
    cost = float(np.sum(pseudo_huber(np.linalg.norm(r, axis=1), delta_px)))
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        rho = np.linalg.norm(r, axis=1)
        w = huber_weights(rho, delta_px)
        Jf = J[:, :, fr]
        A = np.einsum("n,nki,nkj->ij", w, Jf, Jf)
        g = np.einsum("n,nki,nk->i", w, Jf, r)
        d = np.sqrt(np.maximum(np.diag(A), 1e-300))
        As = A / np.outer(d, d)
        gs = g / d
        improved = False
        for _ in range(12):
            try:
                step_s = -np.linalg.solve(As + lam * np.eye(fr.size), gs)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = theta.copy()
            trial[fr] += step_s / d
            if trial[1] <= 0 or trial[2] <= 0 or not 0 <= trial[5] < 1:
                lam *= 10
                continue
            r_try = model.residual_np(trial, streaks)
            c_try = float(np.sum(pseudo_huber(np.linalg.norm(r_try, axis=1), delta_px)))
            if np.isfinite(c_try) and c_try <= cost:
                improved = True
                theta, small = trial, bool(np.all(np.abs(step_s) < step_tol))
                rel = (cost - c_try) / max(cost, 1e-300)
                cost = c_try
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        if not improved:
            converged = True
            break
        if small or rel < rel_tol:
            # A negligible last step: keep the Jacobian of the previous point (it differs by
            # far less than its own uncertainty) and the exact residual of the new one.
            r = r_try
            converged = True
            break
        r, J = ev.evaluate(theta, streaks, tuple(free))
    w = huber_weights(np.linalg.norm(r, axis=1), delta_px)
    if not np.all(np.isfinite(theta)):
        raise CalibError("fit diverged to non-finite parameters: "
                         + ", ".join(THETA_NAMES[i] for i in free))
    return LMResult(theta, it, converged, cost, r, J, w)
