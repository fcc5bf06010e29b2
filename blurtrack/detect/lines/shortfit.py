"""Least-squares endpoints of short streaks (no plateau), batched.

Model of a short streak's profile: a segment ``[a, a + L]`` carrying a line density that
varies quadratically along it, blurred by a Gaussian of known sigma. Brightness is the time the
dot spends per pixel, ``1 / speed``: a dot that slows down during the exposure draws a streak
that brightens towards its slow end, and convexly so (for a constant deceleration the density is
``(v0**2 - 2 a s)**-1/2``); a linear density cannot follow that curvature and pushes both fitted
ends outwards (measured: +0.24 px per end on a 12 px streak whose speed falls from 1.4 to 0.6
times its mean). With ``u = s' - mid`` along the segment:

``m(s) = c0 F0(s) + c1 F1(s) + c2 F2(s)``, the blur of ``c0 + c1 u + c2 u**2`` over the segment:
``F0 = Phi((s - a) / sigma) - Phi((s - b) / sigma)``, ``F1 = (s - mid) F0 + sigma**2 (ga - gb)``,
``F2 = (s - mid)**2 F0 + 2 (s - mid) sigma**2 (ga - gb) + sigma**2 F0
- sigma**2 ((b - s) gb - (a - s) ga)`` (``b = a + L``, ``mid = a + L / 2``, ``ga = g(s - a)``,
``gb = g(s - b)``, ``g`` the Gaussian density): the moments ``∫ w**k g(w) dw`` over the segment.

The amplitudes enter linearly and are solved exactly for every trial ``(a, L)`` (variable
projection); ``(a, L)`` take Gauss-Newton steps from the moments' estimate, with
finite-difference derivatives of the projected residuals (the perturbed basis comes from its
analytic derivative, so only the cheap linear solve is repeated), until they stop moving;
converged rows drop out of the batch. Least squares weighs every sample alike, unlike the
second and third moments, whose far-out noisy samples get large lever arms. A density that
would turn negative on the segment, or a segment shorter than :data:`QUADRATIC_MIN_SIGMAS`
blur sigmas (whose curvature the blur hides: fitted, it trades off against the length and
biased 8 px streaks by +0.1 px), falls back to the linear density.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.lines.normal import normal_cdf_given_exp as _phi

_SQRT_2PI = np.sqrt(2.0 * np.pi)  # the Gaussian's normalisation

#: Shortest segment (in blur sigmas) whose density curvature is fitted.
QUADRATIC_MIN_SIGMAS = 5.0


def _basis(
    s: np.ndarray, a: np.ndarray, L: np.ndarray, sigma: np.ndarray, quadratic: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """``F0``, ``F1``, ``F2`` (``None`` unless ``quadratic``) of shape ``(N, S)`` for rows of
    sample positions ``s``, and the Gaussian densities ``ga = g(s - a)``, ``gb = g(s - b)``
    (their derivatives' building blocks)."""
    a_, b_, sg = a[:, None], (a + L)[:, None], sigma[:, None]
    inv = 1.0 / sg
    ua, ub = (s - a_) * inv, (s - b_) * inv
    ea, eb = np.exp(-0.5 * ua * ua), np.exp(-0.5 * ub * ub)
    F0 = _phi(ua, ea) - _phi(ub, eb)
    ga = ea * (inv / _SQRT_2PI)
    gb = eb * (inv / _SQRT_2PI)
    s2 = sg * sg
    dm = s - 0.5 * (a_ + b_)
    i1 = s2 * (ga - gb)
    F1 = dm * F0 + i1
    if not quadratic:
        return F0, F1, None, ga, gb
    F2 = dm * (dm * F0 + 2.0 * i1) + s2 * (F0 - ((b_ - s) * gb - (a_ - s) * ga))
    return F0, F1, F2, ga, gb


@dataclass
class _State:
    """Basis, amplitudes and residuals ``(N, S)`` of every row at one trial ``(a, L)``."""

    F0: np.ndarray
    F1: np.ndarray
    F2: np.ndarray | None
    ga: np.ndarray
    gb: np.ndarray
    c0: np.ndarray
    c1: np.ndarray
    c2: np.ndarray
    res: np.ndarray
    cost: np.ndarray

    def rows(self, sel: np.ndarray) -> _State:
        """The rows ``sel`` (index or mask) of this state."""
        vals: list[Any] = [
            None if getattr(self, f) is None else getattr(self, f)[sel] for f in _FIELDS
        ]
        return _State(*vals)


_FIELDS = ("F0", "F1", "F2", "ga", "gb", "c0", "c1", "c2", "res", "cost")  # _State's arrays


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...j,...j->...", u, v)


def _project_linear(
    m00: np.ndarray, m01: np.ndarray, m11: np.ndarray, r0: np.ndarray, r1: np.ndarray, L: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``c0, c1`` of the linear density (``(..., N)``) from the normal equations' entries."""
    det = m00 * m11 - m01 * m01
    ok = det > 1e-9 * m00 * m11
    c0 = np.where(ok, (m11 * r0 - m01 * r1) / np.where(ok, det, 1.0), r0 / m00)
    c1 = np.where(ok, (m00 * r1 - m01 * r0) / np.where(ok, det, 1.0), 0.0)
    # The density must stay >= 0 (|c1| <= 2 c0 / L); below 2 px a slope is not resolvable
    # (it trades off against the position) and is dropped. Where c1 changes, c0 is refitted.
    limit = np.where(L >= 2.0, 2.0 * np.maximum(c0, 0.0) / np.maximum(L, 1e-9), 0.0)
    c1_new = np.clip(c1, -limit, limit)
    c0 = np.where(c1_new != c1, (r0 - m01 * c1_new) / m00, c0)
    return c0, c1_new


def _project(
    F0: np.ndarray,
    F1: np.ndarray,
    F2: np.ndarray | None,
    y: np.ndarray,
    L: np.ndarray,
    l_quad: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact linear solve for ``c0, c1, c2`` given the basis ``(..., N, S)`` (zero outside the
    fit window, like ``y``): residuals of that shape and the amplitudes ``(..., N)`` (leading
    axes batch several trial bases). ``F2 is None``, or rows with ``L < l_quad (N,)``: a linear
    density (``c2 = 0``). The 3 × 3 normal equations are solved by their adjugate (batched
    closed form: one numpy call per entry instead of a per-row LAPACK call)."""
    m00, m01, m11 = _dot(F0, F0) + 1e-12, _dot(F0, F1), _dot(F1, F1) + 1e-12
    r0, r1 = _dot(F0, y), _dot(F1, y)
    l0, l1 = _project_linear(m00, m01, m11, r0, r1, L)
    if F2 is None:
        return y - l0[..., None] * F0 - l1[..., None] * F1, l0, l1, np.zeros_like(l0)
    m02, m12, m22, r2 = _dot(F0, F2), _dot(F1, F2), _dot(F2, F2) + 1e-12, _dot(F2, y)
    k00 = m11 * m22 - m12 * m12
    k01 = m02 * m12 - m01 * m22
    k02 = m01 * m12 - m02 * m11
    det = m00 * k00 + m01 * k01 + m02 * k02
    inv = 1.0 / np.where(det > 1e-9 * m00 * m11 * m22, det, np.inf)  # 0: singular, linear
    q0 = (k00 * r0 + k01 * r1 + k02 * r2) * inv
    q1 = (k01 * r0 + (m00 * m22 - m02 * m02) * r1 + (m01 * m02 - m00 * m12) * r2) * inv
    q2 = (k02 * r0 + (m01 * m02 - m00 * m12) * r1 + (m00 * m11 - m01 * m01) * r2) * inv
    # The quadratic density must be >= 0 over the segment: its minimum is at an end or, if
    # convex, at the vertex (clipped into the segment).
    h = 0.5 * L
    u = np.clip(-q1 / np.where(q2 > 0, 2.0 * q2, np.inf), -h, h)
    low = np.minimum(
        np.minimum(q0 - h * (q1 - q2 * h), q0 + h * (q1 + q2 * h)), q0 + u * (q1 + q2 * u)
    )
    quad = (inv != 0) & (l_quad <= L) & (low >= 0) & (q0 > 0)
    c0 = np.where(quad, q0, l0)
    c1 = np.where(quad, q1, l1)
    c2 = np.where(quad, q2, 0.0)
    res = y - c0[..., None] * F0 - c1[..., None] * F1 - c2[..., None] * F2
    return res, c0, c1, c2


def _residual(
    y: np.ndarray,
    w: np.ndarray,
    s: np.ndarray,
    a: np.ndarray,
    L: np.ndarray,
    sigma: np.ndarray,
    quadratic: bool,
) -> _State:
    """Residuals after the exact linear solve for the amplitudes, with the basis (all masked
    by the 0/1 window ``w``; ``y`` must be zero outside it)."""
    F0, F1, F2, ga, gb = _basis(s, a, L, sigma, quadratic)
    F0 *= w
    F1 *= w
    if F2 is not None:
        F2 *= w
    ga *= w
    gb *= w
    res, c0, c1, c2 = _project(F0, F1, F2, y, L, QUADRATIC_MIN_SIGMAS * sigma)
    return _State(F0, F1, F2, ga, gb, c0, c1, c2, res, np.einsum("ij,ij->i", res, res))


def _jacobian(
    st: _State, y: np.ndarray, L: np.ndarray, sigma: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences (step ``h``) of the projected residuals with respect to ``a`` (at
    fixed ``L``) and ``L``, the basis moved by its analytic derivative (exact to ``O(h**2)``).
    With ``F_k = ∫_a^b (u - mid)**k g(s - u) du``: ``dF_k/da = (L/2)**k gb - (-L/2)**k ga
    - k F_(k-1)`` (a shift) and ``dF_k/dL = (L/2)**k gb - (k/2) F_(k-1)``."""
    F0, F1, F2, ga, gb = st.F0, st.F1, st.F2, st.ga, st.gb
    hl = 0.5 * L[:, None]
    # Both perturbations in one batched solve (the cost here is per numpy call).
    P2 = (
        None
        if F2 is None
        else np.stack([F2 + h * (hl * hl * (gb - ga) - 2.0 * F1), F2 + h * (hl * hl * gb - F1)])
    )
    r2, _, _, _ = _project(
        np.stack([F0 + h * (gb - ga), F0 + h * gb]),
        np.stack([F1 + h * (hl * (ga + gb) - F0), F1 + h * (hl * gb - 0.5 * F0)]),
        P2,
        y,
        np.stack([L, L + h]),
        QUADRATIC_MIN_SIGMAS * sigma,
    )
    return (r2[0] - st.res) / h, (r2[1] - st.res) / h


def _steps(
    y: np.ndarray,
    w: np.ndarray,
    s: np.ndarray,
    sigma: np.ndarray,
    a: np.ndarray,
    L: np.ndarray,
    c0: np.ndarray,
    act: np.ndarray,
    *,
    iterations: int,
    tol: float,
    quadratic: bool,
) -> None:
    """Gauss-Newton steps on the rows ``act`` of ``a``, ``L`` and the mean density ``c0``
    (updated in place)."""
    top = y.shape[1] - 1.0
    st = _residual(y[act], w[act], s, a[act], L[act], sigma[act], quadratic)
    c0[act] = st.c0 + st.c2 * L[act] ** 2 / 12.0
    for _ in range(iterations):
        if act.size == 0:
            break
        ya, wa, sga, aa, La = y[act], w[act], sigma[act], a[act], L[act]
        ja, jl = _jacobian(st, ya, La, sga, 1e-3)
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
        trial = _residual(ya, wa, s, a_new, L_new, sga, quadratic)
        take = trial.cost < st.cost
        back = np.flatnonzero(~take)
        if back.size:  # backtracking: a shorter step where the full one did not help
            a_b = np.clip(aa[back] + 0.3 * da[back], 0.0, top)
            L_b = np.clip(La[back] + 0.3 * dl[back], 0.05, np.maximum(top - a_b, 0.05))
            tb = _residual(ya[back], wa[back], s, a_b, L_b, sga[back], quadratic)
            ok_b = tb.cost < st.cost[back]
            a_new[back] = np.where(ok_b, a_b, aa[back])
            L_new[back] = np.where(ok_b, L_b, La[back])
            for f in _FIELDS:  # rows where neither step helped keep their state
                t, n, o = getattr(trial, f), getattr(tb, f), getattr(st, f)
                if t is None:
                    continue
                u = ok_b.reshape((-1,) + (1,) * (n.ndim - 1))
                t[back] = np.where(u, n, o[back])
            take[back] = ok_b
        moved = np.maximum(np.abs(a_new - aa), np.abs(L_new - La))
        a[act], L[act] = a_new, L_new
        c0[act] = trial.c0 + trial.c2 * L_new * L_new / 12.0
        keep = take & (moved >= tol)
        act = act[keep]
        st = trial.rows(keep)


def fit_short(
    y: np.ndarray,
    w: np.ndarray,
    sigma: np.ndarray,
    a0: np.ndarray,
    L0: np.ndarray,
    iterations: int = 2,
    tol: float = 1e-2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``(a, L)`` to profiles ``y (N, S)`` sampled at indices ``0..S-1`` with 0/1 weights
    ``w`` (the fit window), known ``sigma (N,)``, from the start ``a0``, ``L0``.

    At most ``iterations`` Gauss-Newton steps; a row stops once its step (sample units) is
    below ``tol`` (a tenth of the endpoint noise on the simulator's ``realistic`` preset) or no
    longer lowers its cost. Returns ``a``, ``L`` (>= 0) and the mean line density over the
    segment (per sample).
    """
    s = np.arange(y.shape[1], dtype=np.float64)[None, :]
    y = y * w  # the fit sees the window only
    top = y.shape[1] - 1.0
    a = np.clip(np.nan_to_num(a0.astype(np.float64), nan=0.0), 0.0, top)
    L = np.clip(np.nan_to_num(L0.astype(np.float64), nan=0.05), 0.05, np.maximum(top - a, 0.05))
    c0 = np.zeros(a.size)
    _steps(
        y, w, s, sigma, a, L, c0, np.arange(a.size), iterations=iterations, tol=tol, quadratic=True
    )
    return a, L, c0
