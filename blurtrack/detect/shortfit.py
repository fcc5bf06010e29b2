"""Least-squares endpoints of short streaks (no plateau), batched.

Model of a short streak's profile: a segment ``[a, a + L]`` carrying a linearly varying line
density (brightness is proportional to 1 / speed, so an accelerating dot makes a lopsided
streak), blurred by a Gaussian of known sigma:

``m(s) = c0 F0(s) + c1 F1(s)``, ``F0 = Phi((s - a) / sigma) - Phi((s - b) / sigma)``,
``F1 = (s - mid) F0 + sigma**2 (g(s - a) - g(s - b))`` (``b = a + L``, ``mid = a + L / 2``,
``g`` the Gaussian density), i.e. the blur of ``c0 + c1 (u - mid)`` over the segment.

The amplitudes enter linearly and are solved exactly for every trial ``(a, L)`` (variable
projection); ``(a, L)`` take Gauss-Newton steps from the moments' estimate, with
finite-difference derivatives of the projected residuals (the perturbed basis comes from its
analytic derivative, so only the cheap linear solve is repeated), until they stop moving;
converged rows drop out of the batch. Least squares weighs every sample alike, unlike the
second and third moments, whose far-out noisy samples get large lever arms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

_SQRT_2PI = np.sqrt(2.0 * np.pi)


def _basis(s: np.ndarray, a: np.ndarray, L: np.ndarray, sigma: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``F0``, ``F1`` of shape ``(N, S)`` for rows of sample positions ``s``, and the Gaussian
    densities ``ga = g(s - a)``, ``gb = g(s - b)`` (their derivatives' building blocks)."""
    a_, b_, sg = a[:, None], (a + L)[:, None], sigma[:, None]
    inv = 1.0 / sg
    ua, ub = (s - a_) * inv, (s - b_) * inv
    F0 = ndtr(ua) - ndtr(ub)
    ga = np.exp(-0.5 * ua * ua) * (inv / _SQRT_2PI)
    gb = np.exp(-0.5 * ub * ub) * (inv / _SQRT_2PI)
    F1 = (s - 0.5 * (a_ + b_)) * F0 + sg * sg * (ga - gb)
    return F0, F1, ga, gb


@dataclass
class _State:
    """Basis, amplitudes and residuals ``(N, S)`` of every row at one trial ``(a, L)``."""

    F0: np.ndarray
    F1: np.ndarray
    ga: np.ndarray
    gb: np.ndarray
    c0: np.ndarray
    c1: np.ndarray
    res: np.ndarray
    cost: np.ndarray

    def rows(self, sel: np.ndarray) -> _State:
        """The rows ``sel`` (index or mask) of this state."""
        return _State(*(getattr(self, f)[sel] for f in _FIELDS))


_FIELDS = ("F0", "F1", "ga", "gb", "c0", "c1", "res", "cost")


def _project(F0: np.ndarray, F1: np.ndarray, y: np.ndarray, L: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact linear solve for ``c0, c1`` given the basis ``(..., N, S)`` (zero outside the fit
    window, like ``y``): residuals of that shape and the amplitudes ``(..., N)`` (leading axes
    batch several trial bases)."""
    m00 = np.einsum("...j,...j->...", F0, F0) + 1e-12
    m01 = np.einsum("...j,...j->...", F0, F1)
    m11 = np.einsum("...j,...j->...", F1, F1) + 1e-12
    r0 = np.einsum("...j,...j->...", F0, y)
    r1 = np.einsum("...j,...j->...", F1, y)
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
    res = y - c0[..., None] * F0 - c1[..., None] * F1
    return res, c0, c1


def _residual(y: np.ndarray, w: np.ndarray, s: np.ndarray, a: np.ndarray, L: np.ndarray,
              sigma: np.ndarray) -> _State:
    """Residuals after the exact linear solve for ``c0, c1``, with the basis (all masked by
    the 0/1 window ``w``; ``y`` must be zero outside it)."""
    F0, F1, ga, gb = _basis(s, a, L, sigma)
    F0 *= w
    F1 *= w
    ga *= w
    gb *= w
    res, c0, c1 = _project(F0, F1, y, L)
    return _State(F0, F1, ga, gb, c0, c1, res, np.einsum("ij,ij->i", res, res))


def _jacobian(st: _State, y: np.ndarray, L: np.ndarray, h: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences (step ``h``) of the projected residuals with respect to ``a`` (at
    fixed ``L``) and ``L``, the basis moved by its analytic derivative (exact to ``O(h**2)``):
    ``dF0/da = gb - ga``, ``dF1/da = -F0 + (ga + gb) L/2`` (a shift), ``dF0/dL = gb``,
    ``dF1/dL = -F0/2 + gb L/2``."""
    F0, F1, ga, gb = st.F0, st.F1, st.ga, st.gb
    half_L = 0.5 * L[:, None]
    gbh = gb * half_L
    # Both perturbations in one batched solve (the cost here is per numpy call).
    r2, _, _ = _project(np.stack([F0 + h * (gb - ga), F0 + h * gb]),
                        np.stack([F1 + h * ((ga * half_L + gbh) - F0), F1 + h * (gbh - 0.5 * F0)]),
                        y, np.stack([L, L + h]))
    return (r2[0] - st.res) / h, (r2[1] - st.res) / h


def fit_short(y: np.ndarray, w: np.ndarray, sigma: np.ndarray, a0: np.ndarray,
              L0: np.ndarray, iterations: int = 3, tol: float = 1e-3
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``(a, L)`` to profiles ``y (N, S)`` sampled at indices ``0..S-1`` with 0/1 weights
    ``w`` (the fit window), known ``sigma (N,)``, from the start ``a0``, ``L0``.

    At most ``iterations`` Gauss-Newton steps; a row stops once its step (sample units) is
    below ``tol`` or no longer lowers its cost. Returns ``a``, ``L`` (>= 0) and the mean line
    density ``c0`` (per sample).
    """
    s = np.arange(y.shape[1], dtype=np.float64)[None, :]
    y = y * w  # the fit sees the window only
    top = y.shape[1] - 1.0
    a = np.clip(np.nan_to_num(a0.astype(np.float64), nan=0.0), 0.0, top)
    L = np.clip(np.nan_to_num(L0.astype(np.float64), nan=0.05), 0.05, np.maximum(top - a, 0.05))
    st = _residual(y, w, s, a, L, sigma)
    c0 = st.c0.copy()
    act = np.arange(a.size)
    for _ in range(iterations):
        if act.size == 0:
            break
        ya, wa, sga, aa, La = y[act], w[act], sigma[act], a[act], L[act]
        ja, jl = _jacobian(st, ya, La, 1e-3)
        r = st.res
        # Gauss-Newton step for (a, L), with a small damping term.
        gaa = np.einsum("ij,ij->i", ja, ja) * 1.001 + 1e-12
        gll = np.einsum("ij,ij->i", jl, jl) * 1.001 + 1e-12
        gal = np.einsum("ij,ij->i", ja, jl)
        ba = -np.einsum("ij,ij->i", ja, r)
        bl = -np.einsum("ij,ij->i", jl, r)
        det = gaa * gll - gal * gal
        da = np.clip((gll * ba - gal * bl) / det, -1.0, 1.0)
        dl = np.clip((gaa * bl - gal * ba) / det, -1.0, 1.0)
        a_new = np.clip(aa + da, 0.0, top)
        L_new = np.clip(La + dl, 0.05, np.maximum(top - a_new, 0.05))
        trial = _residual(ya, wa, s, a_new, L_new, sga)
        take = trial.cost < st.cost
        back = np.flatnonzero(~take)
        if back.size:  # backtracking: a shorter step where the full one did not help
            a_b = np.clip(aa[back] + 0.3 * da[back], 0.0, top)
            L_b = np.clip(La[back] + 0.3 * dl[back], 0.05, np.maximum(top - a_b, 0.05))
            tb = _residual(ya[back], wa[back], s, a_b, L_b, sga[back])
            ok_b = tb.cost < st.cost[back]
            a_new[back] = np.where(ok_b, a_b, aa[back])
            L_new[back] = np.where(ok_b, L_b, La[back])
            for f in _FIELDS:  # rows where neither step helped keep their state
                t, n, o = getattr(trial, f), getattr(tb, f), getattr(st, f)
                u = ok_b.reshape((-1,) + (1,) * (n.ndim - 1))
                t[back] = np.where(u, n, o[back])
            take[back] = ok_b
        moved = np.maximum(np.abs(a_new - aa), np.abs(L_new - La))
        a[act], L[act], c0[act] = a_new, L_new, trial.c0
        keep = take & (moved >= tol)
        act = act[keep]
        st = trial.rows(keep)
    return a, L, c0
