"""Honest 1-sigma of translation fits (:mod:`calib.natural.motion`).

The translation fit's residuals depend on the calibration parameters ``θ`` *and* on the
nuisance epipoles / travel directions ``d`` (unit 3-vectors, two degrees of freedom each),
which the fit re-estimates at every step (variable projection). Its sigma therefore needs:

1. **The nuisances' uncertainty.** The full Jacobian ``J = [J_θ, J_d]`` (``J_d`` along two
   tangent directions of every ``d``) and the ``θ`` block of ``(Jᵀ W J)⁻¹``, i.e. the
   inverse of the Schur complement ``J_θᵀWJ_θ − J_θᵀWJ_d (J_dᵀWJ_d)⁻¹ J_dᵀWJ_θ``: a ``θ``
   that the epipole can imitate (the principal point against a focus of expansion near the
   image centre) is only as well known as the two together.
2. **Track errors correlated within a frame pair and across neighbouring pairs.** The gyro's
   noise integrated over one frame interval moves every track of that pair alike, and the
   same texture is tracked under nearly the same blur for several pairs: leave-one-cluster-out
   jackknives (linearised: leaving cluster ``c`` out moves the estimate by
   ``(A − A_c)⁻¹ g_c``) clustered by frame pair and by blocks of
   :data:`calib.natural.sigma.BLOCK_PAIRS` pairs; the largest of the plain ``s² A⁻¹`` and the
   two is kept. (Rotation-only fits use sandwiches; a driving session is short, 29 pairs or 6
   blocks in 1 s for 14 parameters and nuisances, and a sandwich with that few clusters is
   biased low, of rank at most the number of clusters. The jackknife is not. It is taken about
   the estimate, not about the clusters' mean: the fit stops on the flat principal point /
   tilt ridge with a gradient left (on a 320×180 drive 1.1 cluster sigmas along cy), and
   centring would drop that; centred, σ(cy) was 1.1 px there against 3.6 px, and the truth
   outside 3σ.)
3. **The unfitted gyro scale matrix** as a *consider* covariance ``S P Sᵀ``,
   ``S = −[(JᵀWJ)⁻¹ JᵀW J_s]_θ`` (the nuisances absorb what they can of a scale error), with
   ``P`` from :data:`calib.natural.sigma.GYRO_SCALE_SIGMA`; a scale matrix given in
   session.yaml counts as known.

Jacobians are forward differences of the fit's own numpy residual (``MotionProblem.residual``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from calib.natural.sigma import BLOCK_PAIRS, GYRO_SCALE_SIGMA, SCALE_NAMES
from calib.params import LAYOUT, THETA_NAMES

if TYPE_CHECKING:
    from calib.natural.motion import MotionProblem

#: Forward-difference step of a nuisance direction (unit vector, radians).
D_STEP = 1e-6


def _fd_step(name: str, theta: np.ndarray) -> float:
    if name in ("fx", "fy", "cx", "cy"):
        return 1e-2
    return 1e-6


def _tangents(d: np.ndarray) -> np.ndarray:
    """Two unit vectors orthogonal to unit ``d`` ``(2, 3)``."""
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(d, u)])


def full_jacobian(
    pb: MotionProblem, theta: np.ndarray, E: np.ndarray, names: tuple[str, ...], r0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(J_θ (N, k), J_d (N, 2G))``: forward differences of the epipolar residuals over the
    named parameters (nuisances held) and over each nuisance direction's two tangents."""
    Jt = np.zeros((r0.size, len(names)))
    for j, n in enumerate(names):
        h = _fd_step(n, theta)
        tp = theta.copy()
        tp[LAYOUT[n]] += h
        Jt[:, j] = (pb.residual(tp, E) - r0) / h
    Jd = np.zeros((r0.size, 2 * len(E)))
    for g in range(len(E)):
        for k, u in enumerate(_tangents(E[g])):
            Ep = E.copy()
            Ep[g] = E[g] + D_STEP * u
            Ep[g] /= np.linalg.norm(Ep[g])
            Jd[:, 2 * g + k] = (pb.residual(theta, Ep) - r0) / D_STEP
    return Jt, Jd


def _jackknife(J: np.ndarray, w: np.ndarray, r: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """Leave-one-cluster-out (linearised) jackknife covariance: cluster ``c`` left out moves
    the estimate by ``(A − A_c)⁻¹ g_c`` (``A_c``, ``g_c``: its normal matrix and gradient);
    ``(C−1)/C Σ δ_c δ_cᵀ`` about the estimate (CR3). Unlike the sandwich it is not biased low
    for few clusters; like it, it keeps the gradient the estimate leaves (the travel direction
    is an eigenvector estimate, not the exact minimiser of the weighted squares)."""
    uniq, inv = np.unique(cluster, return_inverse=True)
    A = (J * w[:, None]).T @ J
    deltas = np.zeros((uniq.size, J.shape[1]))
    for c in range(uniq.size):
        sel = inv == c
        Jc = J[sel]
        Ac = (Jc * w[sel, None]).T @ Jc
        deltas[c] = np.linalg.lstsq(A - Ac, Jc.T @ (w[sel] * r[sel]), rcond=None)[0]
    nc = uniq.size
    return deltas.T @ deltas * ((nc - 1) / max(nc, 1))


def translation_sigma(
    pb: MotionProblem,
    theta: np.ndarray,
    E: np.ndarray,
    fit_idx: tuple[int, ...],
    w: np.ndarray,
    scale_known: bool,
) -> tuple[dict[str, float], dict[str, Any]]:
    """Sigma of the fitted parameters ``theta[fit_idx]`` of a converged translation fit
    (epipoles ``E``, robust weights ``w``; zero weight = outlier or unusable), with the
    three effects of the module docstring, and what went into it."""
    names = tuple(THETA_NAMES[i] for i in fit_idx)
    r = pb.residual(theta, E)
    Jt, Jd = full_jacobian(pb, theta, E, names, r)
    k = len(names)
    keep = w > 0
    J = np.hstack([Jt, Jd])[keep]
    wk, rk = w[keep], r[keep]
    A = (J * wk[:, None]).T @ J
    Ainv = np.linalg.pinv(A)
    dof = max(int(keep.sum()) - J.shape[1], 1)
    s2 = float(np.sum(wk * rk**2)) / dof
    var_plain = s2 * np.diag(Ainv)[:k]
    # without the nuisances' uncertainty (what the fit reported before)
    var_held = s2 * np.diag(np.linalg.pinv((Jt[keep] * wk[:, None]).T @ Jt[keep]))
    pair = pb.pair[keep]
    var_pair = np.diag(_jackknife(J, wk, rk, pair))[:k]
    var_block = np.diag(_jackknife(J, wk, rk, pair // BLOCK_PAIRS))[:k]
    considered = () if scale_known else tuple(n for n in SCALE_NAMES if n not in names)
    var_scale = np.zeros(k)
    sens: dict[str, dict[str, float]] = {}
    if considered:
        Js, _ = full_jacobian(pb, theta, E, considered, r)
        S = -(Ainv @ ((J * wk[:, None]).T @ Js[keep]))[:k]
        prior = np.array([1.0 if n[-2] == n[-1] else 0.5 for n in considered])
        var_scale = GYRO_SCALE_SIGMA**2 * (S**2 @ prior)
        sens = {
            f: {c: float(S[i, j]) for j, c in enumerate(considered)} for i, f in enumerate(names)
        }

    def sd(v: float) -> float:
        return float(np.sqrt(max(v, 0.0)))

    sigma, parts = {}, {}
    for j, n in enumerate(names):
        stat = max(var_plain[j], var_pair[j], var_block[j])
        sigma[n] = sd(stat + var_scale[j])
        parts[n] = {
            "nuisance_held": sd(var_held[j]),
            "fit": sd(var_plain[j]),
            "pair": sd(var_pair[j]),
            "block": sd(var_block[j]),
            "gyro_scale": sd(var_scale[j]),
        }
    info = {
        "model": "translation",
        "nuisance_dof": int(Jd.shape[1]),
        "pairs": int(np.unique(pair).size),
        "block_pairs": BLOCK_PAIRS,
        "gyro_scale_sigma": 0.0 if scale_known else GYRO_SCALE_SIGMA,
        "gyro_scale_considered": list(considered),
        "parts": parts,
        "sensitivity": sens,
    }
    return sigma, info
