"""Frame-correlated gyro noise: a generalised-least-squares refinement (``--frame-noise``).

With exact streaks, what is left at the true parameters is gyro noise, and one frame's streaks
share it: on the ``realistic`` preset a per-frame angular-velocity offset and a linear drift
across the frame's exposure window explain about 90 % of the residual variance. Ordinary least
squares treats it as independent endpoint noise; the frame-clustered sandwich keeps its sigma
honest but the estimate wastes the within-frame geometry. This module weights residuals with
the covariance of that noise model instead (a random effect per frame)::

    r_f = J_f δθ + B_f ν_f + e_f,   ν_f ~ N(0, Σ_ν),   e_f ~ N(0, σ² D_f⁻¹)

``B_f`` (``(m_f, 6)``): the bias columns of the Jacobian (a constant rate offset) and the same
times the streak's time in the exposure window (a linear drift), ``D_f`` the robust weights.
Profiling ``ν_f`` out (Woodbury) gives the weight ``W_f = D − D B (Bᵀ D B + σ² Σ_ν⁻¹)⁻¹ Bᵀ D``.
``Σ_ν`` and ``σ²`` are first estimated from the data by moments (per-frame least-squares
``ν̂_f`` minus their own noise). That overstates ``Σ_ν``: what the two modes leave is itself
correlated within a frame, so ``ν̂_f`` are noisier than ``σ² (Bᵀ D B)⁻¹`` says, and a loose
prior lets the drift mode absorb the time shift and readout (a readout error is a time drift
down the rows). So the prior precision is scaled by the factor of :data:`PRIOR_SCALES` that
minimises the predicted sandwich covariance's log-determinant proxy ``Σ log σ_i`` at the start
point (a first-order prediction, no refit per factor). The weighting is only a weighting:
whatever ``Σ_ν``, the estimate stays consistent, and its covariance is the frame-clustered
sandwich of the weighted score.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import GROUPS
from calib.solve import Evaluator, lm_driver
from calib.uncertainty import MODEL_FLOOR_PX

#: Bias entries of theta (their Jacobian columns span the per-frame rate offset).
BIAS = GROUPS["bias"]
#: Candidate factors on the moment estimate of the prior precision (1e6: practically OLS).
PRIOR_SCALES = (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1e6)
#: Readout (fraction of the exposure) below which the drift mode is left out.
MIN_DRIFT_READOUT = 0.1


def nuisance_columns(
    J: np.ndarray,
    streaks: StreakSet,
    height: int,
    readout_s: float,
) -> np.ndarray:
    """``(N, m, 6)``: rate-offset columns and drift columns (offset times the streak's
    normalised time in its frame's exposure window, in [-1/2, 1/2]). ``(N, m, 3)`` (offset
    only) when the readout is under :data:`MIN_DRIFT_READOUT` of the exposure: then the rows
    share one window and a drift is indistinguishable from an offset."""
    jb = J[:, :, list(BIAS)]
    if readout_s < MIN_DRIFT_READOUT * float(np.median(streaks.exposure_s)):
        return jb
    row = (streaks.start[:, 1] + streaks.end[:, 1]) / (2 * height)
    span = readout_s + streaks.exposure_s
    tau = readout_s * (row - 0.5) / np.maximum(span, 1e-9)
    return np.concatenate([jb, jb * tau[:, None, None]], axis=2)


@dataclass(frozen=True)
class FrameModel:
    """Per-frame noise model: frame groups, nuisance columns, robust weights, prior ratio."""

    groups: tuple[np.ndarray, ...]
    B: np.ndarray  # (N, m, k), k = 6 (offset, drift) or 3 (offset)
    d: np.ndarray  # (N,) robust weights
    prior: np.ndarray  # (k,) σ² / Σ_ν (diagonal prior precision relative to the noise)
    sigma2: float  # per-coordinate noise variance after the frame effects

    @classmethod
    def estimate(
        cls, r: np.ndarray, B: np.ndarray, frames: np.ndarray, d: np.ndarray
    ) -> FrameModel:
        _, inv = np.unique(frames, return_inverse=True)
        groups = tuple(np.flatnonzero(inv == k) for k in range(inv.max() + 1))
        nus, diag_inv, ss, dof = [], [], 0.0, 0
        for g in groups:
            Bf, rf, df = _flat(B[g]), r[g].reshape(-1), np.repeat(d[g], r.shape[1])
            BDB = Bf.T @ (df[:, None] * Bf)
            if np.linalg.matrix_rank(BDB) < BDB.shape[0]:
                continue
            Binv = np.linalg.inv(BDB)
            nu = Binv @ (Bf.T @ (df * rf))
            e = rf - Bf @ nu
            ss += float(e @ (df * e))
            dof += rf.size - nu.size
            nus.append(nu)
            diag_inv.append(np.diag(Binv))
        if len(nus) < 3 or dof <= 0:
            raise CalibError("too few frames with enough streaks for the frame-noise model")
        sigma2 = max(ss / dof, 1e-12)
        var_nu = np.mean(np.square(nus), axis=0) - sigma2 * np.mean(diag_inv, axis=0)
        prior = sigma2 / np.maximum(var_nu, 1e-6 * np.mean(np.square(nus), axis=0) + 1e-30)
        return cls(groups, B, d, prior, sigma2)

    def normal_equations(
        self,
        J: np.ndarray,
        r: np.ndarray,
        free: tuple[int, ...],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """``A (p, p)``, ``g (p,)``, per-frame scores ``G (F, p)`` and cost of the GLS weight."""
        p = len(free)
        A = np.zeros((p, p))
        G = np.zeros((len(self.groups), p))
        cost = 0.0
        for k, g in enumerate(self.groups):
            Jf = _flat(J[g][:, :, list(free)])
            Bf, rf = _flat(self.B[g]), r[g].reshape(-1)
            df = np.repeat(self.d[g], r.shape[1])
            C = Bf.T @ (df[:, None] * Bf) + np.diag(self.prior)
            JDB = Jf.T @ (df[:, None] * Bf)
            BDr = Bf.T @ (df * rf)
            A += Jf.T @ (df[:, None] * Jf) - JDB @ np.linalg.solve(C, JDB.T)
            G[k] = Jf.T @ (df * rf) - JDB @ np.linalg.solve(C, BDr)
            cost += float(rf @ (df * rf) - BDr @ np.linalg.solve(C, BDr))
        return A, G.sum(axis=0), G, cost

    def cost(self, r: np.ndarray) -> float:
        total = 0.0
        for g in self.groups:
            Bf, rf = _flat(self.B[g]), r[g].reshape(-1)
            df = np.repeat(self.d[g], r.shape[1])
            C = Bf.T @ (df[:, None] * Bf) + np.diag(self.prior)
            BDr = Bf.T @ (df * rf)
            total += float(rf @ (df * rf) - BDr @ np.linalg.solve(C, BDr))
        return total


def _flat(a: np.ndarray) -> np.ndarray:
    return a.reshape(a.shape[0] * a.shape[1], -1) if a.ndim == 3 else a.reshape(-1)


def sandwich(
    fm: FrameModel,
    J: np.ndarray,
    r: np.ndarray,
    free: tuple[int, ...],
) -> tuple[np.ndarray, np.ndarray]:
    """Frame-clustered sandwich covariance ``(p, p)`` and sigma ``(p,)`` (never below the
    plain ``σ² A⁻¹``, ``σ`` at least the model's own accuracy
    :data:`calib.uncertainty.MODEL_FLOOR_PX`) of the weighted estimate."""
    A, _, G, _ = fm.normal_equations(J, r, free)
    dA = np.sqrt(np.maximum(np.diag(A), 1e-300))
    Ainv = np.linalg.pinv(A / np.outer(dA, dA)) / np.outer(dA, dA)
    nc = G.shape[0]
    cov = Ainv @ (G.T @ G * (nc / max(nc - 1, 1))) @ Ainv
    s2 = max(fm.sigma2, MODEL_FLOOR_PX**2)
    return cov, np.sqrt(np.maximum(np.diag(cov), s2 * np.diag(Ainv)))


def choose_prior(
    fm: FrameModel,
    J: np.ndarray,
    r: np.ndarray,
    free: tuple[int, ...],
) -> tuple[FrameModel, float]:
    """The model with the prior factor of :data:`PRIOR_SCALES` of least ``Σ log σ_i``."""
    best: tuple[float, float, FrameModel] | None = None
    for k in PRIOR_SCALES:
        cand = FrameModel(fm.groups, fm.B, fm.d, fm.prior * k, fm.sigma2)
        score = float(np.sum(np.log(sandwich(cand, J, r, free)[1])))
        if best is None or score < best[0]:
            best = (score, k, cand)
    assert best is not None
    return best[2], best[1]


@dataclass(frozen=True)
class GLSResult:
    theta: np.ndarray
    iterations: int
    converged: bool
    sigma: np.ndarray  # (p,)
    covariance: np.ndarray  # (p, p)
    frame_model: FrameModel
    prior_scale: float


def gls_refine(
    ev: Evaluator,
    streaks: StreakSet,
    theta0: np.ndarray,
    free: tuple[int, ...],
    weights: np.ndarray,
    height: int,
    readout_s: float,
    start: tuple[np.ndarray, np.ndarray] | None = None,
    max_iter: int = 10,
    step_tol: float = 0.02,
) -> GLSResult:
    """Refine an (ordinary robust) optimum under the frame-noise weighting.

    Levenberg–Marquardt on the GLS cost with the noise model estimated at the start point and
    the robust weights ``weights`` held; returns the estimate and its frame-clustered sandwich
    covariance (``A⁻¹ Σ_f g_f g_fᵀ A⁻¹``), never below the plain ``σ² A⁻¹``. ``start``: the
    residual and Jacobian at ``theta0`` if already known. Converged when every scaled step is
    below ``step_tol`` noise sigmas; the loop is :func:`calib.solve.lm_driver` (bounds
    table, singular-system guard).
    """
    if not all(i in free for i in BIAS):
        raise CalibError("the frame-noise model needs the gyro bias among the fitted parameters")
    theta = np.asarray(theta0, float).copy()
    r, J = start if start is not None else ev.evaluate(theta, streaks, free)
    fm = FrameModel.estimate(
        r, nuisance_columns(J, streaks, height, readout_s), streaks.frame, weights
    )
    fm, scale = choose_prior(fm, J, r, free)
    state: dict[str, Any] = {"r": r, "J": J, "fm": fm, "first": True}

    def linearise(th: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        if not state["first"]:
            state["r"], state["J"] = ev.evaluate(th, streaks, free)
            f = state["fm"]
            B = nuisance_columns(state["J"], streaks, height, readout_s)
            state["fm"] = FrameModel(f.groups, B, f.d, f.prior, f.sigma2)
        state["first"] = False
        A, g, _, cost = state["fm"].normal_equations(state["J"], state["r"], free)
        return A, g, cost

    def trial_cost(th: np.ndarray) -> float:
        state["r_try"] = ev.residual(th, streaks)
        return state["fm"].cost(state["r_try"])

    tol = step_tol * max(np.sqrt(fm.sigma2), MODEL_FLOOR_PX)
    res = lm_driver(theta, free, linearise, trial_cost, tol, max_iter, rel_tol=0.0, lam0=1e-6)
    theta, it, converged = res.theta, res.iterations, res.converged
    fm, J = state["fm"], state["J"]
    r = state["r_try"] if res.ended_on_small_step else state["r"]
    cov, sig = sandwich(fm, J, r, free)
    return GLSResult(theta, it, converged, sig, cov, fm, scale)
