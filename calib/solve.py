"""Robust Levenberg–Marquardt on CasADi's exact Jacobian (Gauss–Newton Hessian ``JᵀWJ``).

Jacobians come from :class:`calib.jacobian.JacobianEvaluator` (one SX function per streak,
mapped over the streaks). The robust loss is pseudo-Huber on each streak's error
``ρ = |r|`` (its endpoint residual, and its weighted centre-line residuals when used):
``δ² (sqrt(1 + (ρ/δ)²) − 1)``, minimised by iteratively reweighted Gauss–Newton with weights
``1 / sqrt(1 + (ρ/δ)²)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.data import StreakSet
from calib.errors import CalibError
from calib.jacobian import JacobianEvaluator
from calib.params import THETA_NAMES, bounded_step


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
    residual: np.ndarray  # (N, m): endpoint (2) [+ weighted centre-line points]
    jacobian: np.ndarray  # (N, m, N_THETA), zero in the columns of fixed parameters
    weights: np.ndarray  # (N,)


def levenberg_marquardt(
    ev: JacobianEvaluator,
    streaks: StreakSet,
    theta0: np.ndarray,
    free: tuple[int, ...],
    delta_px: float,
    max_iter: int = 30,
    step_tol: float = 1e-6,
    rel_tol: float = 1e-8,
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
            # Bounds table (calib.params.BOUNDS): the readout is projected onto [0, 1) s
            # (rejecting such steps stalled global-shutter fits at their start); a
            # non-positive focal length is refused.
            trial = bounded_step(trial)
            if trial is None:
                lam *= 10
                continue
            step_s = (trial[fr] - theta[fr]) * d  # the step taken, after projection
            r_try = ev.residual(trial, streaks)
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
        # A new centre-line association changes the cost at the same parameters.
        cost = float(np.sum(pseudo_huber(np.linalg.norm(r, axis=1), delta_px)))
    w = huber_weights(np.linalg.norm(r, axis=1), delta_px)
    if not np.all(np.isfinite(theta)):
        raise CalibError(
            "fit diverged to non-finite parameters: " + ", ".join(THETA_NAMES[i] for i in free)
        )
    return LMResult(theta, it, converged, cost, r, J, w)
