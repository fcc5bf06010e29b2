"""Honest 1-sigma of natural-scene fits: correlated tracks and the unfitted gyro scale.

The fit's own sigma (:mod:`calib.uncertainty`: the larger of ``s² A⁻¹`` and the sandwich
clustered by frame pair) leaves out two things that natural scenes have:

1. **Track errors correlated across neighbouring frame pairs.** The same texture is tracked
   under nearly the same blur for several consecutive pairs, so the residual left by one
   patch repeats; a sandwich clustered by blocks of :data:`BLOCK_PAIRS` consecutive pairs
   keeps that correlation (the larger of the two sandwiches is used).
2. **The gyro's scale and cross-axis matrix**, under ``--gyro-scale-prior consider`` (the
   default fits it under a prior instead: :mod:`calib.natural.scale`). Left unfitted (it
   trades with the focal lengths), it is not known: an error ``δs`` of its six entries moves
   the fitted parameters by ``S δs`` with ``S = −(J_fᵀ W J_f)⁻¹ J_fᵀ W J_s`` (Jacobians of
   the same residual at the optimum). The *consider* covariance ``S P Sᵀ`` with
   ``P`` from :data:`GYRO_SCALE_SIGMA` per matrix entry is added (``sensitivity`` in the
   summary is ``S``). A scale matrix given in
   session.yaml (not the identity) counts as known (``σ_s = 0``); fitted entries are
   estimated, not considered.

Jacobians are forward differences of :meth:`calib.problem.ResidualModel.residual_np`, the
model the fit itself evaluates (numpy side of the CasADi twin).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from calib.data import StreakSet, relative_gyro
from calib.fitcore import FitOptions
from calib.params import LAYOUT, N_THETA, THETA_NAMES
from calib.problem import ResidualModel, choose_substeps
from calib.result import CalibResult

#: Consecutive frame pairs per cluster of the block sandwich.
BLOCK_PAIRS = 5
#: 1-sigma of each gyro scale / cross-axis entry when session.yaml does not give the matrix
#: (a MEMS gyro after factory trim; the simulator's realistic preset draws the same).
GYRO_SCALE_SIGMA = 0.003
#: Residuals beyond this many robust sigmas get no weight (as the fit's outlier rejection).
OUTLIER_SIGMAS = 5.0
SCALE_NAMES = tuple(THETA_NAMES[i] for i in range(*LAYOUT["scale"].indices(N_THETA)))


def gyro_scale_known(calib: Calibration) -> bool:
    """Whether a calibration's ``gyro_scale_matrix`` was given (anything but the identity): a
    scale matrix from session.yaml counts as known, and is neither fitted nor considered."""
    return not np.allclose(calib.gyro_scale_matrix, np.eye(3), atol=0, rtol=0)


def _step(name: str) -> float:
    return 1e-2 if name in ("fx", "fy", "cx", "cy") else 1e-6


def _jacobian(
    model: ResidualModel,
    theta: np.ndarray,
    streaks: StreakSet,
    names: tuple[str, ...],
    r0: np.ndarray,
) -> np.ndarray:
    """``(2N, k)`` forward differences of the stacked residuals (``r0`` at ``theta``)."""
    cols = []
    for n in names:
        h = _step(n)
        tp = theta.copy()
        tp[LAYOUT[n]] += h
        cols.append((model.residual_np(tp, streaks) - r0).reshape(-1) / h)
    return np.stack(cols, axis=1)


def _block_sandwich(
    J: np.ndarray, r: np.ndarray, w: np.ndarray, block: np.ndarray, Ainv: np.ndarray
) -> np.ndarray:
    g = (J * (w * r)[:, None]).reshape(-1, 2, J.shape[1]).sum(axis=1)
    uniq, inv = np.unique(block, return_inverse=True)
    G = np.zeros((uniq.size, J.shape[1]))
    np.add.at(G, inv, g)
    nc = uniq.size
    return Ainv @ (G.T @ G * (nc / max(nc - 1, 1))) @ Ainv


def honest_sigma(
    res: CalibResult, streaks: StreakSet, gyro: GyroTrace, options: FitOptions
) -> tuple[dict[str, float], dict[str, Any]]:
    """Sigma of ``res``'s fitted parameters with both effects of the module docstring, and
    what went into it (per-parameter fit, block and scale parts)."""
    base = res.initial
    cam = base.camera
    g = relative_gyro(gyro.upsampled(options.gyro_upsample), streaks.t0_s)
    n_sub = choose_substeps(streaks, cam.height, max(2 * cam.readout_s, 0.05))
    model = ResidualModel(g, base.R_cam_imu, cam.dist, cam.height, n_sub)
    theta = np.array([res.values[n] for n in THETA_NAMES], float)
    fitted = tuple(n for n in res.fitted if n in res.sigma)
    r2 = model.residual_np(theta, streaks)
    norm = np.linalg.norm(r2, axis=1)
    s = max(float(np.median(norm)) / 1.177, 1e-6)  # 2-D norm's median -> per-axis sigma
    w1 = 1.0 / (1.0 + (norm / (2.0 * s)) ** 2)
    w1[norm > OUTLIER_SIGMAS * s] = 0.0
    w = np.repeat(w1, 2)
    r = r2.reshape(-1)
    Jf = _jacobian(model, theta, streaks, fitted, r2)
    A = (Jf * w[:, None]).T @ Jf
    Ainv = np.linalg.pinv(A)
    block = np.asarray(streaks.frame) // BLOCK_PAIRS
    var_block = np.diag(_block_sandwich(Jf, r, w, block, Ainv))
    known = gyro_scale_known(base)
    considered = () if known else tuple(n for n in SCALE_NAMES if n not in fitted)
    var_scale = np.zeros(len(fitted))
    sens: dict[str, dict[str, float]] = {}
    if considered:
        Js = _jacobian(model, theta, streaks, considered, r2)
        S = -Ainv @ ((Jf * w[:, None]).T @ Js)
        # theta holds the symmetric part of M − I: an off-diagonal entry averages two
        # independent matrix entries (the antisymmetric part is a mounting rotation, fitted)
        prior = np.array([1.0 if n[-2] == n[-1] else 0.5 for n in considered])
        var_scale = GYRO_SCALE_SIGMA**2 * (S**2 @ prior)
        sens = {
            f: {c: float(S[i, j]) for j, c in enumerate(considered)} for i, f in enumerate(fitted)
        }
    sigma, parts = {}, {}
    for k, n in enumerate(fitted):
        fit = float(res.sigma[n])
        blk = float(np.sqrt(max(var_block[k], 0.0)))
        sc = float(np.sqrt(max(var_scale[k], 0.0)))
        sigma[n] = float(np.sqrt(max(fit, blk) ** 2 + sc**2))
        parts[n] = {"fit": fit, "block": blk, "gyro_scale": sc}
    info = {
        "block_pairs": BLOCK_PAIRS,
        "gyro_scale_sigma": 0.0 if known else GYRO_SCALE_SIGMA,
        "gyro_scale_considered": list(considered),
        "parts": parts,
        "sensitivity": sens,
    }
    return sigma, info
