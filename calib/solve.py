"""Robust Levenberg–Marquardt on CasADi's exact Jacobian (Gauss–Newton Hessian ``JᵀWJ``).

Residuals and Jacobians come from :class:`calib.grid.GridEvaluator` (orientation integrated
once per evaluation on a fixed grid; one small SX function per residual, mapped), with
centre lines :class:`calib.centreline.CentreGridEvaluator`. The robust loss is pseudo-Huber
on each streak's error ``ρ = |r|`` (its endpoint residual, and its weighted centre-line
residuals when used): ``δ² (sqrt(1 + (ρ/δ)²) − 1)``, minimised by iteratively reweighted
Gauss–Newton with weights ``1 / sqrt(1 + (ρ/δ)²)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import THETA_NAMES, bounded_step
from calib.uncertainty import information


class Evaluator(Protocol):
    """What the solver needs of a residual model (:class:`calib.grid.GridEvaluator`,
    :class:`calib.centreline.CentreGridEvaluator`)."""

    def residual(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray: ...

    def evaluate(
        self, theta: np.ndarray, streaks: StreakSet, free: tuple[int, ...]
    ) -> tuple[np.ndarray, np.ndarray]: ...


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


#: A linearisation at theta: ``(A (p, p), g (p,), cost)`` of the free entries (Gauss–Newton
#: information, gradient, cost there).
Linearise = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, float]]


@dataclass(frozen=True)
class DriverResult:
    theta: np.ndarray
    iterations: int
    converged: bool
    #: True when the last accepted step was negligible: the caller's last linearisation is of
    #: the previous point, the last ``trial_cost`` call of the returned theta.
    ended_on_small_step: bool


def lm_driver(
    theta0: np.ndarray,
    free: tuple[int, ...],
    linearise: Linearise,
    trial_cost: Callable[[np.ndarray], float],
    step_tol: float,
    max_iter: int = 30,
    rel_tol: float = 1e-8,
    lam0: float = 1e-3,
    progress: Callable[[int, float], None] | None = None,
) -> DriverResult:
    """The one Levenberg–Marquardt loop of the calibration (robust fit and GLS refinement).

    Steps are solved in Jacobian-column-scaled coordinates (Marquardt) with the bounds table
    :data:`calib.params.BOUNDS` applied to every trial (the readout projected onto its bound,
    a non-positive focal length or implausible scale refused), a singular system raising the
    damping (``LinAlgError`` guard). Converged when the step actually taken, measured as the
    change it makes to the fitted residuals ``sqrt(δᵀ A δ)``, is below ``step_tol`` or the
    next one is predicted so (below half the last and its size times that ratio below
    ``step_tol``), the relative cost decrease is below ``rel_tol``, or no step decreases the
    cost. ``progress(iteration, cost)`` is called after every iteration.
    """
    if not free:
        raise CalibError("no parameter left to fit")
    theta = np.asarray(theta0, float).copy()
    fr = np.asarray(free)
    lam = lam0
    converged = small = False
    prev_size = 0.0
    it = 0
    A, g, cost = linearise(theta)
    trial: np.ndarray | None
    for it in range(1, max_iter + 1):
        d = np.sqrt(np.maximum(np.diag(A), 1e-300))
        As, gs = A / np.outer(d, d), g / d
        improved = False
        rel = 0.0
        for _ in range(12):
            try:
                step_s = -np.linalg.solve(As + lam * np.eye(fr.size), gs)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = theta.copy()
            trial[fr] += step_s / d
            trial = bounded_step(trial)
            if trial is None:
                lam *= 10
                continue
            step_s = (trial[fr] - theta[fr]) * d  # the step taken, after projection
            c_try = trial_cost(trial)
            if np.isfinite(c_try) and c_try <= cost:
                improved = True
                # The step's size in the information metric, sqrt(δᵀ A δ): the change of the
                # fitted residuals (px); it bounds every parameter's change by that over the
                # residual sigma times the parameter's own sigma (Cauchy–Schwarz).
                size = float(np.sqrt(max(step_s @ As @ step_s, 0.0)))
                # Converged: a small step, or the next one predicted small (the robust
                # Gauss–Newton iteration converges linearly near the optimum: each step a
                # fixed fraction of the last, measured from the last two).
                rate = size / prev_size if prev_size > 0 else 1.0
                small = size < step_tol or (rate < 0.5 and size * rate < step_tol)
                theta, prev_size = trial, size
                rel = (cost - c_try) / max(cost, 1e-300)
                cost = c_try
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        if progress is not None:
            progress(it, cost)
        if not improved:
            converged, small = True, False
            break
        if small or rel < rel_tol:
            # A negligible last step: keep the linearisation of the previous point (it
            # differs by far less than its own uncertainty).
            converged, small = True, True
            break
        A, g, cost = linearise(theta)
    if not np.all(np.isfinite(theta)):
        raise CalibError(
            "fit diverged to non-finite parameters: " + ", ".join(THETA_NAMES[i] for i in free)
        )
    return DriverResult(theta, it, converged, small)


def levenberg_marquardt(
    ev: Evaluator,
    streaks: StreakSet,
    theta0: np.ndarray,
    free: tuple[int, ...],
    delta_px: float,
    max_iter: int = 30,
    step_tol: float = 1e-6,
    rel_tol: float = 1e-8,
    lam0: float = 1e-3,
    progress: Callable[[int, float], None] | None = None,
) -> LMResult:
    """Minimise the pseudo-Huber endpoint cost over the ``free`` entries of theta
    (:func:`lm_driver`; IRLS weights from each linearisation).

    ``step_tol`` is in pixels of residual (a step below a few percent of the residual sigma
    is far below the parameter's own 1-sigma).
    """
    fr = list(free)
    state: dict[str, np.ndarray] = {}

    def cost_of(r: np.ndarray) -> float:
        return float(np.sum(pseudo_huber(np.linalg.norm(r, axis=1), delta_px)))

    def linearise(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        r, J = ev.evaluate(theta, streaks, tuple(free))
        state["r"], state["J"] = r, J
        w = huber_weights(np.linalg.norm(r, axis=1), delta_px)
        A = information(J, w, tuple(free))
        g = (J[:, :, fr] * w[:, None, None]).reshape(-1, len(fr)).T @ r.reshape(-1)
        # A new centre-line association changes the cost at the same parameters.
        return A, g, cost_of(r)

    def trial_cost(theta: np.ndarray) -> float:
        state["r_try"] = ev.residual(theta, streaks)
        return cost_of(state["r_try"])

    res = lm_driver(
        theta0, free, linearise, trial_cost, step_tol, max_iter, rel_tol, lam0, progress
    )
    r = state["r_try"] if res.ended_on_small_step else state["r"]
    w = huber_weights(np.linalg.norm(r, axis=1), delta_px)
    return LMResult(res.theta, res.iterations, res.converged, cost_of(r), r, state["J"], w)
