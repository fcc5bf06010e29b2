"""1-sigma uncertainty from the Jacobian at the optimum, and observability diagnostics.

Two covariance estimates are formed from the Gauss–Newton information ``A = JᵀWJ``:

- ``s² A⁻¹`` with ``s²`` the weighted residual variance (independent endpoint noise);
- the frame-clustered sandwich ``A⁻¹ (Σ_f g_f g_fᵀ) A⁻¹`` with ``g_f = J_fᵀ W r_f`` summed over
  each frame's streaks: gyro noise moves every streak of a frame together, so residuals are
  correlated within a frame and the first estimate alone would be over-confident.

The reported sigma is the larger of the two, per parameter. The residual sigma in the first has
a floor of :data:`MODEL_FLOOR_PX`: the numerical model itself (1 ms integration sub-steps, gyro
interpolation) differs from continuous motion by about a hundredth of a pixel, an error that
noise-free data would otherwise report with an impossibly small sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.params import THETA_NAMES

#: Floor of the per-coordinate residual sigma (px): the numerical model's own accuracy.
MODEL_FLOOR_PX = 0.01
#: Normalised information eigenvalue below which a direction counts as unobservable.
UNOBSERVABLE_EIG = 1e-9
#: Correlation above which a pair of parameters is reported as hard to separate.
HIGH_CORRELATION = 0.98
#: 1-sigma above which a parameter is reported as weakly determined (theta units).
WEAK_SIGMA = {
    "timeshift_s": 1e-3,
    "fx": 5.0,
    "fy": 5.0,
    "cx": 5.0,
    "cy": 5.0,
    "readout_s": 2e-3,
    "bias_x": 2e-3,
    "bias_y": 2e-3,
    "bias_z": 2e-3,
    "rot_x": 0.0087,
    "rot_y": 0.0087,
    "rot_z": 0.0087,
    **{f"scale_{a}": 5e-3 for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
}


#: A fitted parameter whose sigma exceeds this many times its :data:`WEAK_SIGMA` is not
#: determined by the data at all (a time offset known to no better than 0.1 s, a focal
#: length to 500 px): no calibration is written from such a fit.
UNDETERMINED_FACTOR = 100.0


def undetermined(sigma: dict[str, float]) -> list[str]:
    """Names of the parameters in ``sigma`` (theta units) that are not finite or exceed
    :data:`UNDETERMINED_FACTOR` times their :data:`WEAK_SIGMA`.

    >>> undetermined({"timeshift_s": 2e-4, "fx": 519026.7, "readout_s": float("nan")})
    ['fx', 'readout_s']
    """
    return [
        k
        for k, v in sigma.items()
        if k in WEAK_SIGMA and not (np.isfinite(v) and v <= UNDETERMINED_FACTOR * WEAK_SIGMA[k])
    ]


@dataclass(frozen=True)
class Uncertainty:
    free: tuple[int, ...]
    covariance: np.ndarray  # (p, p) in theta units
    sigma: np.ndarray  # (p,)
    correlation: np.ndarray  # (p, p)
    residual_sigma_px: float  # per residual coordinate
    warnings: tuple[str, ...]


def information(J: np.ndarray, w: np.ndarray, free: tuple[int, ...]) -> np.ndarray:
    """``Σ_n w_n J_nᵀ J_n`` over the ``free`` columns ``(p, p)`` (one matrix product: numpy's
    three-operand einsum is an unblocked loop, 100x slower on a fit's 10⁵ residuals)."""
    Jw = J[:, :, list(free)] * np.sqrt(w)[:, None, None]
    M = Jw.reshape(-1, Jw.shape[2])
    return M.T @ M


def unobservable(A: np.ndarray, free: tuple[int, ...]) -> list[int]:
    """Theta indices that dominate the near-null directions of the information matrix."""
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    ev, vec = np.linalg.eigh(A / np.outer(d, d))
    out: list[int] = []
    for k in np.flatnonzero(ev < UNOBSERVABLE_EIG * max(ev.max(), 1e-300)):
        out.append(free[int(np.argmax(np.abs(vec[:, k])))])
    zero = [free[i] for i in np.flatnonzero(np.diag(A) <= 1e-300)]
    return sorted(set(out) | set(zero))


def estimate(
    J: np.ndarray, r: np.ndarray, w: np.ndarray, frames: np.ndarray, free: tuple[int, ...]
) -> Uncertainty:
    """Covariance of the free parameters at the optimum (see the module docstring).

    Args:
        J: ``(N, m, 18)`` Jacobian; r: ``(N, m)`` residuals, px (columns 0-1 the endpoint,
            the rest weighted centre-line residuals); w: ``(N,)`` robust weights;
        frames: ``(N,)`` frame index of each streak (the clusters).
    """
    fr = list(free)
    A = information(J, w, free)
    Jf = J[:, :, fr]
    p = len(fr)
    m = 2 * r.shape[0]
    # Endpoint noise from the endpoint columns (centre-line columns carry their weights).
    s2 = max(float(np.sum(w[:, None] * r[:, :2] ** 2) / max(m - p, 1)), MODEL_FLOOR_PX**2)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    Ainv = np.linalg.pinv(A / np.outer(d, d)) / np.outer(d, d)
    cov_plain = s2 * Ainv
    g = np.einsum("n,nki,nk->ni", w, Jf, r)
    uniq, inv = np.unique(frames, return_inverse=True)
    G = np.zeros((uniq.size, p))
    np.add.at(G, inv, g)
    nc = uniq.size
    B = G.T @ G * (nc / max(nc - 1, 1))
    cov_cluster = Ainv @ B @ Ainv
    var = np.maximum(np.diag(cov_plain), np.diag(cov_cluster))
    sig = np.sqrt(var)
    # Report the plain structure scaled to the chosen variances (a valid covariance).
    sp = np.sqrt(np.maximum(np.diag(cov_plain), 1e-300))
    corr = cov_plain / np.outer(sp, sp)
    cov = corr * np.outer(sig, sig)
    warns: list[str] = []
    for a in range(p):
        name = THETA_NAMES[fr[a]]
        if sig[a] > WEAK_SIGMA[name]:
            warns.append(
                f"{name} is weakly determined by this motion "
                f"(1-sigma {sig[a]:.3g} > {WEAK_SIGMA[name]:.3g})"
            )
        for b in range(a + 1, p):
            if abs(corr[a, b]) > HIGH_CORRELATION:
                warns.append(
                    f"{name} and {THETA_NAMES[fr[b]]} are strongly correlated "
                    f"({corr[a, b]:+.3f}); the motion hardly separates them"
                )
    return Uncertainty(tuple(free), cov, sig, corr, float(np.sqrt(s2)), tuple(warns))


def excitation_warnings(omega_cam: np.ndarray) -> list[str]:
    """Warnings on the camera-frame angular velocity ``(M, 3)`` (rad/s) during exposures."""
    rms = np.sqrt(np.mean(np.asarray(omega_cam, float) ** 2, axis=0))
    out = []
    pan = float(np.hypot(rms[0], rms[1]))
    if pan < 1e-3:
        out.append(
            f"almost no pan/tilt motion (rms {pan:.2g} rad/s): time shift, focal lengths "
            f"and readout are weakly observed"
        )
    elif rms[2] < 0.15 * pan:
        out.append(
            f"little roll about the optical axis (rms {rms[2]:.3g} rad/s vs pan/tilt "
            f"{pan:.3g} rad/s): readout and principal point are weakly observed"
        )
    return out
