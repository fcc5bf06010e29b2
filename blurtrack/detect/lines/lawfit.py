"""Least-squares endpoints of short streaks whose time law is known, batched.

A streak's light along its line is the time its dot spends there: sampled uniformly in time,
the dot's positions ``x_k = a + L f_k`` (``k = 0..K-1``) each carry the same light, and the
profile is their sum blurred by the cross-section Gaussian,

``m(s) = c sum_k w_k g(s - a - L f_k)``, ``g`` the Gaussian density of sigma ``sigma``,
``w_k`` the trapezoid weights of uniform times (summing to 1).

``f_k`` is the *time law*: where along the start-to-end chord the dot is at each time, as a
fraction of the chord (0 at the start, 1 at the end; outside ``[0, 1]`` where the dot runs
past an end and back, a hook). The gyro's predicted curve gives it
(:mod:`blurtrack.detect.gyro.gyromeasure`); the start ``a``, the length ``L`` and the light
``c`` are the image's, fitted here. The law fixes only how the light is spread between the
ends, the part of the profile that the blur hides on a short streak: a dot that slows down at
both ends (a shake turning just outside the exposure) brightens both ends, which the short
fit's linear density reads as a longer segment (:mod:`~blurtrack.detect.lines.shortfit`: both
ends outwards, 0.5-1 px each on the ``dense`` preset's 6 px streaks at a turn), and a dot
fastest at its ends as a shorter one. A streak long enough for edge fits is fitted whole under
its law only where its dot rests near an end
(:data:`~blurtrack.detect.lines.endpoints.REST_FRACTION`): the edge fit puts that end at
the half level of the resting spot's peak, about a sigma outwards (1.5 px on a 14 px
streak whose dot gathers speed as ``t**3``; 1.8-2 px on the ``realistic`` preset's held-out
seed 9), and only where the row is neither saturated nor crossing (a neighbour's light in
the window, or an unclipped profile, would move the whole fit) and no longer than its law's
samples resolve (half a sigma apart, :data:`LAW_SAMPLES`).

``c`` enters linearly and is solved exactly for each trial ``(a, L)`` (variable projection);
``(a, L)`` take Gauss-Newton steps with the analytic derivatives of the basis (the Kaufman
approximation: the derivative of ``c`` is left out of the Jacobian), each step accepted only
where it lowers the cost, halved otherwise.
"""

from __future__ import annotations

import numpy as np

_SQRT_2PI = float(np.sqrt(2.0 * np.pi))

#: Gauss-Newton steps at most; a row stops once its step is below the tolerance (samples).
LAW_ITERATIONS = 8
LAW_TOL = 1e-3
#: Samples of a time law: 33 points over a 6 px streak lie 0.2 px apart, a seventh of the
#: narrowest blur sigma (1.3 px), so their blurred sum is the continuous law's to 1e-6.
LAW_SAMPLES = 33


def time_law(pts: np.ndarray) -> np.ndarray | None:
    """The time law ``(LAW_SAMPLES,)`` of a curve ``pts (K, 2)`` sampled uniformly in time,
    start first: the position along the start-to-end chord, as a fraction of it, at
    :data:`LAW_SAMPLES` uniform times. None where the chord is under a pixel (a dot that
    barely moves: no direction to project on)."""
    pts = np.asarray(pts, float)
    if pts.ndim != 2 or pts.shape[0] < 2:
        return None
    d = pts[-1] - pts[0]
    c2 = float(d @ d)
    if c2 < 1.0:
        return None
    f = (pts - pts[0]) @ d / c2
    t = np.linspace(0.0, 1.0, pts.shape[0])
    return np.asarray(np.interp(np.linspace(0.0, 1.0, LAW_SAMPLES), t, f), float)


def _weights(K: int) -> np.ndarray:
    w = np.ones(K)
    w[[0, -1]] = 0.5
    return w / w.sum()


def _basis(
    s: np.ndarray, a: np.ndarray, L: np.ndarray, sigma: np.ndarray, law: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``B``, ``dB/da``, ``dB/dL`` ``(N, S)`` at sample positions ``s (1, S)``."""
    wk = _weights(law.shape[1])
    x = s[:, :, None] - (a[:, None] + L[:, None] * law)[:, None, :]  # (N, S, K)
    sg = sigma[:, None, None]
    g = np.exp(-0.5 * (x / sg) ** 2) * (wk / (_SQRT_2PI * sg))
    B = g.sum(axis=2)
    gx = g * (x / (sg * sg))
    return B, gx.sum(axis=2), np.einsum("nsk,nk->ns", gx, law)


def _project(B: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The light ``c (N,)``, residuals ``(N, S)`` and cost ``(N,)`` of the basis ``B``."""
    c = np.einsum("ns,ns->n", B, y) / (np.einsum("ns,ns->n", B, B) + 1e-300)
    res = y - c[:, None] * B
    return c, res, np.einsum("ns,ns->n", res, res)


def fit_law(
    y: np.ndarray,
    w: np.ndarray,
    sigma: np.ndarray,
    law: np.ndarray,
    a0: np.ndarray,
    L0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit the start ``a`` and length ``L`` (sample units) of profiles ``y (N, S)`` sampled
    at ``0..S-1`` with 0/1 weights ``w`` (the fit window), the blur ``sigma (N,)`` (samples)
    and the time laws ``law (N, K)`` (:func:`time_law`), from ``a0``, ``L0``. Returns ``a``,
    ``L`` (>= 0.05) and the mean line density over the segment (per sample)."""
    N, S = y.shape
    s = np.arange(S, dtype=np.float64)[None, :]
    y = y * w
    top = S - 1.0
    a = np.clip(np.nan_to_num(a0.astype(np.float64), nan=0.0), 0.0, top)
    L = np.clip(np.nan_to_num(L0.astype(np.float64), nan=1.0), 0.05, top)
    B, dBa, dBL = _basis(s, a, L, sigma, law)
    B, dBa, dBL = B * w, dBa * w, dBL * w
    c, res, cost = _project(B, y)
    act = np.arange(N)
    for _ in range(LAW_ITERATIONS):
        if act.size == 0:
            break
        ja, jl = c[act, None] * dBa[act], c[act, None] * dBL[act]
        r = res[act]
        gaa = np.einsum("ns,ns->n", ja, ja) * 1.001 + 1e-12
        gll = np.einsum("ns,ns->n", jl, jl) * 1.001 + 1e-12
        gal = np.einsum("ns,ns->n", ja, jl)
        ba, bl = -np.einsum("ns,ns->n", ja, r), -np.einsum("ns,ns->n", jl, r)
        det = gaa * gll - gal * gal
        # Residual r = y - c B; its derivative is -c dB, so the step solves for -J.
        da = np.clip(-(gll * ba - gal * bl) / det, -1.0, 1.0)
        dl = np.clip(-(gaa * bl - gal * ba) / det, -1.0, 1.0)
        moved = np.zeros(act.size, bool)
        for scale in (1.0, 0.5, 0.25):
            todo = ~moved
            if not todo.any():
                break
            rows = act[todo]
            a_t = np.clip(a[rows] + scale * da[todo], 0.0, top)
            L_t = np.clip(L[rows] + scale * dl[todo], 0.05, top)
            Bt, dat, dlt = _basis(s, a_t, L_t, sigma[rows], law[rows])
            wt = w[rows]
            Bt, dat, dlt = Bt * wt, dat * wt, dlt * wt
            ct, rt, costt = _project(Bt, y[rows])
            better = costt < cost[rows]
            sel = rows[better]
            a[sel], L[sel], c[sel], cost[sel] = a_t[better], L_t[better], ct[better], costt[better]
            res[sel], B[sel], dBa[sel], dBL[sel] = rt[better], Bt[better], dat[better], dlt[better]
            moved[np.flatnonzero(todo)[better]] = True
        # Rows that stalled, or whose full step was under the tolerance, stop.
        act = act[moved & (np.maximum(np.abs(da), np.abs(dl)) >= LAW_TOL)]
    return a, L, c / np.maximum(L, 0.05)
