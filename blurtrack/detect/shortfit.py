"""Least-squares endpoints of short streaks (no plateau), batched.

Model of a short streak's profile: a segment ``[a, a + L]`` carrying a linearly varying line
density (brightness is proportional to 1 / speed, so an accelerating dot makes a lopsided
streak), blurred by a Gaussian of known sigma:

``m(s) = c0 F0(s) + c1 F1(s)``, ``F0 = Phi((s - a) / sigma) - Phi((s - b) / sigma)``,
``F1 = (s - mid) F0 + sigma**2 (g(s - a) - g(s - b))`` (``b = a + L``, ``mid = a + L / 2``,
``g`` the Gaussian density), i.e. the blur of ``c0 + c1 (u - mid)`` over the segment.

The amplitudes enter linearly and are solved exactly for every trial ``(a, L)`` (variable
projection); ``(a, L)`` take a few Gauss-Newton steps with finite-difference derivatives from
the moments' estimate. Least squares weighs every sample alike, unlike the second and third
moments, whose far-out noisy samples get large lever arms.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

_SQRT_2PI = np.sqrt(2.0 * np.pi)


def _basis(s: np.ndarray, a: np.ndarray, L: np.ndarray, sigma: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """``F0``, ``F1`` of shape ``(N, S)`` for rows of sample positions ``s``."""
    a_, b_, sg = a[:, None], (a + L)[:, None], sigma[:, None]
    ua, ub = (s - a_) / sg, (s - b_) / sg
    F0 = ndtr(ua) - ndtr(ub)
    ga = np.exp(-0.5 * ua * ua) / (sg * _SQRT_2PI)
    gb = np.exp(-0.5 * ub * ub) / (sg * _SQRT_2PI)
    F1 = (s - 0.5 * (a_ + b_)) * F0 + sg * sg * (ga - gb)
    return F0, F1


def _residual(y: np.ndarray, w: np.ndarray, s: np.ndarray, a: np.ndarray, L: np.ndarray,
              sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals ``(N, S)`` after the exact linear solve for ``c0, c1``, and the amplitudes."""
    F0, F1 = _basis(s, a, L, sigma)
    F0w, F1w = F0 * w, F1 * w
    m00 = (F0w * F0).sum(axis=1) + 1e-12
    m01 = (F0w * F1).sum(axis=1)
    m11 = (F1w * F1).sum(axis=1) + 1e-12
    r0 = (F0w * y).sum(axis=1)
    r1 = (F1w * y).sum(axis=1)
    det = m00 * m11 - m01 * m01
    ok = det > 1e-9 * m00 * m11
    c0 = np.where(ok, (m11 * r0 - m01 * r1) / np.where(ok, det, 1.0), r0 / m00)
    c1 = np.where(ok, (m00 * r1 - m01 * r0) / np.where(ok, det, 1.0), 0.0)
    # The density must stay >= 0 (|c1| <= 2 c0 / L); below 2 px a slope is not resolvable
    # (it trades off against the position) and is dropped. Where c1 changes, c0 is refitted.
    limit = np.where(L >= 2.0, 2.0 * np.maximum(c0, 0.0) / np.maximum(L, 1e-9), 0.0)
    c1_new = np.clip(c1, -limit, limit)
    changed = c1_new != c1
    c0 = np.where(changed, (r0 - m01 * c1_new) / m00, c0)
    c1 = c1_new
    res = (y - c0[:, None] * F0 - c1[:, None] * F1) * w
    return res, c0, c1


def fit_short(y: np.ndarray, w: np.ndarray, sigma: np.ndarray, a0: np.ndarray,
              L0: np.ndarray, iterations: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``(a, L)`` to profiles ``y (N, S)`` sampled at indices ``0..S-1`` with 0/1 weights
    ``w`` (the fit window), known ``sigma (N,)``, from the start ``a0``, ``L0``.

    Returns ``a``, ``L`` (>= 0) and the mean line density ``c0`` (per sample).
    """
    s = np.arange(y.shape[1], dtype=np.float64)[None, :]
    top = y.shape[1] - 1.0
    a = np.clip(np.nan_to_num(a0.astype(np.float64), nan=0.0), 0.0, top)
    L = np.clip(np.nan_to_num(L0.astype(np.float64), nan=0.05), 0.05, np.maximum(top - a, 0.05))
    h = 1e-3
    r, _, _ = _residual(y, w, s, a, L, sigma)
    for _ in range(iterations):
        ra, _, _ = _residual(y, w, s, a + h, L, sigma)
        rl, _, _ = _residual(y, w, s, a, L + h, sigma)
        ja, jl = (ra - r) / h, (rl - r) / h
        # Gauss-Newton step for (a, L), with a small damping term.
        gaa = (ja * ja).sum(axis=1) * 1.001 + 1e-12
        gll = (jl * jl).sum(axis=1) * 1.001 + 1e-12
        gal = (ja * jl).sum(axis=1)
        ba = -(ja * r).sum(axis=1)
        bl = -(jl * r).sum(axis=1)
        det = gaa * gll - gal * gal
        da = np.clip((gll * ba - gal * bl) / det, -1.0, 1.0)
        dl = np.clip((gaa * bl - gal * ba) / det, -1.0, 1.0)
        cost_old = (r * r).sum(axis=1)
        moved = np.zeros(a.shape, bool)
        a_next, L_next, r_next = a.copy(), L.copy(), r.copy()
        for scale in (1.0, 0.3):  # backtracking: keep the first step that helps
            a_new = np.clip(a + scale * da, 0.0, top)
            L_new = np.clip(L + scale * dl, 0.05, np.maximum(top - a_new, 0.05))
            r_new, _, _ = _residual(y, w, s, a_new, L_new, sigma)
            take = ~moved & ((r_new * r_new).sum(axis=1) < cost_old)
            a_next = np.where(take, a_new, a_next)
            L_next = np.where(take, L_new, L_next)
            r_next = np.where(take[:, None], r_new, r_next)
            moved |= take
            if moved.all():
                break
        a, L, r = a_next, L_next, r_next
        if not moved.any():
            break
    _, c0, _ = _residual(y, w, s, a, L, sigma)
    return a, L, c0
