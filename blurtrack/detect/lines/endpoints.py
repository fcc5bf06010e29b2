"""Sub-pixel streak endpoints from brightness profiles (batched over the streaks of a frame).

At an end, the profile ``I(s)`` (cross-section integral along the centre line) is an erf edge
``P(s) Phi((s - s0) / sigma)`` around the true endpoint ``s0``: the true end is where the
profile is at half the local plateau, not where it vanishes. We locate ``s0`` by the edge's
area, which is linear in the data and unbiased under noise: for a plateau ``P(s) = P + g (s -
s_in)`` the integral of ``I`` from outside the streak to a point ``s_in`` on the plateau is
``P d - g d**2 / 2 + g sigma**2 / 2`` with ``d = s_in - s0`` (across ``s_in`` the blur brings
``g sigma**2 / 2`` more light from the denser side than it takes back). Brightness is
``1 / speed``, and a dot that slows down or speeds up makes it convex along the streak, which a
line extrapolated to the end under-fills, pushing the end outwards; so ``d`` is refined under
the density of a constant acceleration, ``(alpha + beta x)**-1/2`` (:func:`_time_law_density`).
Streaks too short to have a plateau at each end use the profile's first three moments (a
segment of linearly varying brightness, :func:`linear_density_segment`), then a least-squares
fit (:mod:`~blurtrack.detect.lines.shortfit`).

All positions here are in sample-index units of uniformly sampled profiles; rows of the
matrices are streaks, padded with zeros past each row's length.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from blurtrack.detect.lines.lawfit import fit_law
from blurtrack.detect.lines.normal import normal_cdf
from blurtrack.detect.lines.ragged import row_nanmedian
from blurtrack.detect.lines.shortfit import fit_short

#: Plateau fit window (samples) and how far inside the half-level crossing it starts (sigmas).
PLATEAU_WINDOW = 7
PLATEAU_INSET_SIGMAS = 2.0
#: Margin (sigmas) beyond the half-peak crossings over which short profiles' moments are taken.
MOMENT_MARGIN_SIGMAS = 3.0
#: Where other light lies beyond an end (the profile rises again, outwards, from its minimum
#: between ``3 sigma + 1`` samples and this many sigmas beyond the half-level crossing), the
#: edge area starts at that minimum, the erf's own tail beyond it (at most ``sigma G(-1.5) =
#: 0.03 sigma`` of area) modelled, and the baseline is zero: the neighbour's light past the
#: dip is not read.
EDGE_LOW_SIGMAS = 1.5
#: ... "rises again": by more than the edge's own erf can hold anywhere past that minimum,
#: ``Phi(-EDGE_LOW_SIGMAS)`` = 6.7 % of the plateau; the edge alone falls monotonically.
EDGE_RISE = float(normal_cdf(np.array(-EDGE_LOW_SIGMAS)))
#: A streak with plateaus is fitted under its law where its dot spends more than this share
#: of the exposure within 15 % of the chord from one end (0.15 at constant speed).
REST_FRACTION = 0.3


def plateau_extent(sigma: float | np.ndarray) -> float | np.ndarray:
    """The shortest lit extent (samples, between the quarter-level crossings) on which both
    ends get edge fits (a plateau inside each edge's inset, and the fit window); a shorter
    streak is fitted whole (its moments, then the short or the law fit)."""
    return 2.0 * PLATEAU_INSET_SIGMAS * sigma + PLATEAU_WINDOW


@dataclass(frozen=True)
class EdgeFit:
    """Per streak (``(N,)`` each): endpoint positions at both ends (index units from the
    row's first sample), plateau levels there, whether each end came from an edge fit, and
    whether the moments method was used (short streak)."""

    pos_a: np.ndarray
    pos_b: np.ndarray
    plateau_a: np.ndarray
    plateau_b: np.ndarray
    short: np.ndarray
    valid: np.ndarray


def _at(A: np.ndarray, x: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """Linear interpolation of each row of ``A`` at fractional indices ``x`` (``(N,)`` or
    ``(N, K)``), clamped to the row's samples."""
    rows = np.arange(A.shape[0]).reshape((-1,) + (1,) * (x.ndim - 1))
    hi = (lens - 1).reshape(rows.shape).astype(np.float64)
    x = np.clip(x, 0.0, hi)
    i0 = np.floor(x).astype(np.int64)
    i1 = np.minimum(i0 + 1, hi.astype(np.int64))
    f = x - i0
    return A[rows, i0] * (1 - f) + A[rows, i1] * f


def _first_crossing(
    A: np.ndarray, lens: np.ndarray, level: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fractional index where each row first rises through ``level``, and whether it does."""
    cols = np.arange(A.shape[1])[None, :]
    above = (level[:, None] <= A) & (cols < lens[:, None])
    has = np.asarray(above.any(axis=1))
    k = np.argmax(above, axis=1)
    rows = np.arange(A.shape[0])
    km1 = np.maximum(k - 1, 0)
    a0, a1 = A[rows, km1], A[rows, k]
    den = np.where(a1 != a0, a1 - a0, 1.0)
    f = np.clip((level - a0) / den, 0.0, 1.0)
    return np.where(k > 0, km1 + f, 0.0), has


def _plateau(
    A: np.ndarray, lens: np.ndarray, s_in: np.ndarray, rise: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares line through ``PLATEAU_WINDOW`` samples from ``s_in`` on, each divided by
    the edge's remaining rise ``rise (N, PLATEAU_WINDOW)``: value at ``s_in``, slope, whether
    the window fits inside the row, and the divided samples ``(N, PLATEAU_WINDOW)``."""
    j = np.arange(PLATEAU_WINDOW, dtype=np.float64)
    v = _at(A, s_in[:, None] + j[None, :], lens) / rise
    jc = j - j.mean()
    slope = (v @ jc) / float(jc @ jc)
    value = v.mean(axis=1) - slope * j.mean()
    ok = s_in + PLATEAU_WINDOW - 1 <= lens - 1
    return value, slope, ok, v


def _time_law_density(
    v: np.ndarray, value: np.ndarray, slope: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plateau as the density of a dot under constant acceleration: brightness is
    ``1 / speed`` and ``speed**2`` is linear in position, so ``1 / density**2`` is a line.
    Fitted to the window samples ``v (N, W)`` (baseline removed): ``alpha``, ``beta`` of
    ``density(s_in + x) = (alpha + beta x)**-1/2``, and whether that fit is usable (all samples
    positive); elsewhere the linear plateau (``value``, ``slope``) in the same form to first
    order. A linear density extrapolated to the edge under-fills a convex one (a dot slowing
    down, or speeding up, towards the end) and pushes the endpoint outwards."""
    j = np.arange(v.shape[1], dtype=np.float64)
    jc = j - j.mean()
    pos = np.all(v > 0, axis=1)
    q = 1.0 / np.where(v > 0, v, 1.0) ** 2
    beta = (q @ jc) / float(jc @ jc)
    alpha = q.mean(axis=1) - beta * j.mean()
    good = pos & (alpha > 0)
    lin_alpha = 1.0 / np.where(value > 0, value, 1.0) ** 2
    lin_beta = -2.0 * slope * lin_alpha / np.where(value > 0, value, 1.0)
    return np.where(good, alpha, lin_alpha), np.where(good, beta, lin_beta), good


def _tail_area(z: np.ndarray) -> np.ndarray:
    """``G(z) = z Phi(z) + phi(z)``: area under ``Phi`` from minus infinity to ``z``."""
    return np.asarray(z * normal_cdf(z) + np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi))


def _profile_minimum(A: np.ndarray, lens: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Index of each row's least sample within ``[lo, hi]`` (``lo`` where that is empty)."""
    cols = np.arange(A.shape[1], dtype=np.float64)[None, :]
    win = (cols >= lo[:, None]) & (cols <= hi[:, None]) & (cols < lens[:, None])
    k = np.argmin(np.where(win, A, np.inf), axis=1).astype(np.float64)
    return np.where(win.any(axis=1), np.maximum(k, lo), lo)


def _cumulative(A: np.ndarray) -> np.ndarray:
    """Trapezoid integral of each row from index 0 to every index, same shape as ``A``."""
    C = np.empty(A.shape)
    C[:, 0] = 0.0
    np.cumsum(0.5 * (A[:, 1:] + A[:, :-1]), axis=1, out=C[:, 1:])
    return C


def _integral_to(A: np.ndarray, C: np.ndarray, x: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """Integral of each (piecewise-linear) row from index 0 to fractional index ``x``."""
    rows = np.arange(A.shape[0])
    x = np.clip(x, 0.0, (lens - 1).astype(np.float64))
    i0 = np.floor(x).astype(np.int64)
    i1 = np.minimum(i0 + 1, lens - 1)
    f = x - i0
    a0, a1 = A[rows, i0], A[rows, i1]
    return C[rows, i0] + f * (a0 + 0.5 * f * (a1 - a0))


def rising_edges(
    A: np.ndarray, lens: np.ndarray, sigma: np.ndarray, guess: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Endpoint (fractional index), plateau level and validity of the rising edge at the
    START of every row of ``A (N, L)``. ``guess``: a first plateau level per row.

    The plateau is fitted from ``PLATEAU_INSET_SIGMAS`` sigmas inside the half-level crossing
    on, with the window's samples divided by the erf still rising there; the edge's area up to
    the window start then gives the endpoint, including the erf tail beyond it:
    ``M = P (d + sigma psi(d / sigma))``, ``psi(x) = phi(x) - x Phi(-x)``.

    Where other light lies beyond the end (:data:`EDGE_LOW_SIGMAS`, :data:`EDGE_RISE`), the
    area starts at the profile's minimum there, less the erf's own tail beyond it, ``P sigma
    G((s_lo - s0) / sigma)`` (:func:`_tail_area`), so that the neighbour's light past the dip
    does not move the end, and the baseline is zero (the signal is background subtracted): one
    from the samples beyond the end would be that neighbour's light and move the end inwards.
    Elsewhere the area starts ``3 sigma + 1`` samples out, less a baseline from the samples
    beyond (where there are at least four).
    """
    s_half, has = _first_crossing(A, lens, 0.5 * guess)
    ok = has.copy()
    j = np.arange(PLATEAU_WINDOW, dtype=np.float64)
    for _ in range(2):
        s_in = s_half + PLATEAU_INSET_SIGMAS * sigma
        x = s_in[:, None] + j[None, :]
        rise = np.maximum(normal_cdf((x - s_half[:, None]) / sigma[:, None]), 0.5)
        value, slope, fits, v = _plateau(A, lens, s_in, rise)
        ok &= fits & (value > 0)
        s_half, has = _first_crossing(A, lens, 0.5 * np.where(value > 0, value, guess))
        ok &= has
    s_far = np.maximum(s_half - 3.0 * sigma - 1.0, 0.0)
    s_lo = _profile_minimum(A, lens, s_far, s_half - EDGE_LOW_SIGMAS * sigma)
    cols = np.arange(A.shape[1], dtype=np.float64)[None, :]
    outer = cols <= s_lo[:, None]
    peak_out = np.max(np.where(outer, A, -np.inf), axis=1)
    lit_beyond = peak_out - _at(A, s_lo, lens) > EDGE_RISE * value
    s_lo = np.where(lit_beyond, s_lo, s_far)
    w_lo = s_in - s_lo
    C = _cumulative(A)
    # Local baseline from the samples beyond s_far (when there are enough of them and no
    # other light lies there).
    n_tail = np.floor(s_far).astype(np.int64)
    S = np.concatenate([np.zeros((A.shape[0], 1)), np.cumsum(A, axis=1)], axis=1)
    base = np.where(n_tail >= 4, S[np.arange(A.shape[0]), n_tail] / np.maximum(n_tail, 1), 0.0)
    base = np.where(lit_beyond, 0.0, base)
    M = _integral_to(A, C, s_in, lens) - _integral_to(A, C, s_lo, lens) - base * (s_in - s_lo)
    P = value - base
    v = v - base[:, None]
    ok &= P > 0
    P = np.where(P > 0, P, 1.0)
    d = M / P
    for _ in range(3):
        z = d / sigma
        psi = np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi) - z * normal_cdf(-z)
        tail = np.where(lit_beyond, sigma * _tail_area((d - w_lo) / sigma), 0.0)
        d = (M + 0.5 * slope * (d * d - sigma * sigma)) / P - sigma * psi + tail
    # Refined under the constant-acceleration density: the bulk of the edge's mass,
    # ∫_{-d}^{0} (alpha + beta x)**-1/2 dx = 2 d / (sqrt(alpha) + sqrt(alpha - beta d)), in place
    # of the linear density's P d - g d**2 / 2, and the blur terms with that density's value
    # at the end and slope at s_in. Newton from the linear model's d.
    alpha, beta, _ = _time_law_density(v, P, slope)
    sa = np.sqrt(alpha)
    g_in = -0.5 * beta / (alpha * sa)
    d_lin = d
    for _ in range(2):
        z = d / sigma
        psi = np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi) - z * normal_cdf(-z)
        se = np.sqrt(np.maximum(alpha - beta * d, alpha / 16.0))  # at most 4x the plateau
        tail = np.where(lit_beyond, sigma * _tail_area((d - w_lo) / sigma) / se, 0.0)
        f = 2.0 * d / (sa + se) + sigma * psi / se + 0.5 * g_in * sigma * sigma - tail - M
        df = normal_cdf(z) / se
        step = np.where(np.isfinite(f) & (df > 1e-12), f / np.where(df > 1e-12, df, 1.0), 0.0)
        d = d - np.clip(step, -sigma, sigma)
    # A refinement is a correction of a few tenths of a pixel; a larger one means the window
    # is no plateau (a crossing, a dip): the linear model's end stands.
    d = np.where(np.isfinite(d) & (np.abs(d - d_lin) <= sigma), d, d_lin)
    return s_in - d, P, ok


def _skew_of_slope(beta: np.ndarray) -> np.ndarray:
    """Skewness of the density ``1 + 2 beta x`` on ``x in [-1/2, 1/2]`` (``|beta| <= 1``)."""
    return (-beta / 60 + beta**3 / 108) / (1 / 12 - beta**2 / 36) ** 1.5


_BETA = np.linspace(1.0, -1.0, 201)  # skewness increases along this table
_SKEW = _skew_of_slope(_BETA)  # the skewness at each table slope (inverted by interpolation)


def linear_density_segment(
    mean: np.ndarray, var: np.ndarray, mu3: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The segment ``[lo, hi]`` carrying a linearly varying density with the given mean,
    variance and third central moment (moments of the profile with the blur's variance
    removed; a Gaussian blur adds nothing to the third moment). Brightness is proportional
    to 1 / speed, so an accelerating short streak is lopsided: assuming a uniform density
    would shift it towards its bright end. Returns ``lo``, ``hi`` and the mean density per
    unit mass (``1 / length``). For density ``1 + 2 beta x`` on ``x in [-1/2, 1/2]`` (times L):
    mean ``L beta / 6``, variance ``L^2 (1/12 - beta^2/36)``, third moment
    ``L^3 (-beta/60 + beta^3/108)``.

    >>> lo, hi, _ = linear_density_segment(np.array([5.0]), np.array([12.0]), np.array([0.0]))
    >>> float(lo[0]), float(hi[0])
    (-1.0, 11.0)
    """
    var = np.maximum(var, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        skew = np.where(var > 0, mu3 / np.maximum(var, 1e-12) ** 1.5, 0.0)
    beta = np.interp(skew, _SKEW, _BETA)
    # Below ~2 px the skewness is mostly noise: fall back to a uniform density.
    beta = np.where(var * 12.0 < 4.0, 0.0, beta)
    L = np.sqrt(var / (1 / 12 - beta**2 / 36))
    lo = mean - L * (0.5 + beta / 6)
    return lo, lo + L, 1.0 / np.maximum(L, 1.0)


def reverse_rows(A: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """Each row's first ``lens[i]`` samples reversed (padding kept)."""
    cols = np.arange(A.shape[1])[None, :]
    src = np.where(cols < lens[:, None], lens[:, None] - 1 - cols, cols)
    return np.take_along_axis(A, src, axis=1)


def fit_edges(
    A: np.ndarray,
    lens: np.ndarray,
    sigma: np.ndarray,
    law: np.ndarray | None = None,
    law_whole: np.ndarray | None = None,
) -> EdgeFit:
    """Endpoints of every streak from its uniformly sampled profile.

    Args:
        A: ``(N, L)`` profiles, zero-padded past ``lens``.
        lens: ``(N,)`` number of samples per row.
        sigma: ``(N,)`` edge sigma per row in index units.
        law: ``(N, K)`` predicted time laws (NaN rows: none), oriented along the rows: short
            streaks with one are fitted under it (:func:`~blurtrack.detect.lines.lawfit.fit_law`)
            instead of a quadratic density.
        law_whole: ``(N,)`` rows with plateaus that may be fitted whole under their law,
            where their dot rests near an end (:data:`REST_FRACTION`); None: none. Such rows
            come back ``short`` (their ends are the whole profile's).
    """
    N = A.shape[0]
    peak = A.max(axis=1)
    # First plateau guess: the median of the clearly lit samples (a crossing or a slow spot
    # can make the peak many times the plateau, so the peak is no reference).
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: no lit sample
        m1 = row_nanmedian(np.where(A > 0, A, np.nan)) if N else peak
        lit = np.where(0.3 * np.nan_to_num(m1)[:, None] < A, A, np.nan)
        guess = np.nan_to_num(row_nanmedian(lit), nan=0.0) if N else peak
    # Both ends at once: the rows of A, then the reversed rows (end B's edge rises first).
    AA = np.concatenate([A, reverse_rows(A, lens)])
    lens2 = np.concatenate([lens, lens])
    sigma2, guess2 = np.concatenate([sigma, sigma]), np.concatenate([guess, guess])
    # Edge fits only where a plateau can fit: the lit extent (quarter-level crossings, outside
    # the half-level ends) must hold both insets and the window; the rest is short anyway.
    c4, has4 = _first_crossing(AA, lens2, 0.25 * guess2)
    extent = (lens - 1) - c4[N:] - c4[:N]
    cand = has4[:N] & has4[N:] & (extent >= plateau_extent(sigma))
    p2, P2, ok2 = np.zeros(2 * N), np.ones(2 * N), np.zeros(2 * N, bool)
    sel = np.flatnonzero(np.concatenate([cand, cand]))
    if sel.size:
        p2[sel], P2[sel], ok2[sel] = rising_edges(AA[sel], lens2[sel], sigma2[sel], guess2[sel])
    pa, Pa, oka = p2[:N], P2[:N], ok2[:N]
    pb, Pb, okb = (lens - 1) - p2[N:], P2[N:], ok2[N:]
    short = ~(oka & okb) | (pb - pa < 2 * PLATEAU_INSET_SIGMAS * sigma + PLATEAU_WINDOW)
    # Moments of the profile for short streaks: within the half-peak crossings +- 3 sigma + 1.
    c2, has2 = _first_crossing(AA, lens2, 0.5 * np.concatenate([peak, peak]))
    lo, has_lo, hi_rev, has_hi = c2[:N], has2[:N], c2[N:], has2[N:]
    lawful = np.zeros(N, bool) if law is None else np.isfinite(law).all(axis=1)
    if law is not None and law_whole is not None:
        # Rows with plateaus: only where the dot rests near an end (edge fits put that end
        # at the half level of the resting spot's peak, outwards by about a sigma).
        with np.errstate(invalid="ignore"):
            rest = np.maximum((law < 0.15).mean(axis=1), (law > 0.85).mean(axis=1))
        # ... and short enough for the law's samples to lie within half a sigma of each
        # other (their blurred sum is then smooth): 21 px at a 1.3 px sigma.
        fine = extent <= 0.5 * (law.shape[1] - 1) * sigma
        lawful &= short | (law_whole & (rest > REST_FRACTION) & fine)
    else:
        lawful &= short
    if lawful.any():
        # A streak with a law is fitted whole, also where it has plateaus: the edges find the
        # light's extent, the law where in it the dot started and ended. Its window runs
        # between the quarter-level crossings of its lit level (a dot resting at one end
        # makes a peak that the half-peak crossings would cut the rest of the streak at).
        short = short | lawful
        lo = np.where(lawful & has4[:N], c4[:N], lo)
        hi_rev = np.where(lawful & has4[N:], c4[N:], hi_rev)
        has_lo = np.where(lawful, has_lo | has4[:N], has_lo)
        has_hi = np.where(lawful, has_hi | has4[N:], has_hi)
    lo = np.maximum(lo - MOMENT_MARGIN_SIGMAS * sigma - 1.0, 0.0)
    hi = np.minimum((lens - 1) - hi_rev + MOMENT_MARGIN_SIGMAS * sigma + 1.0, lens - 1.0)
    cols = np.arange(A.shape[1], dtype=np.float64)[None, :]
    inside = (cols >= lo[:, None]) & (cols <= hi[:, None])
    outside = ~inside & (cols < lens[:, None])
    n_out = outside.sum(axis=1)
    # Baseline from the samples outside the window; no clipping of negative samples inside
    # (clipping noise would bias every moment).
    base = np.where(n_out >= 3, (A * outside).sum(axis=1) / np.maximum(n_out, 1), 0.0)
    w = np.where(inside, A - base[:, None], 0.0)
    sw = np.where(w.sum(axis=1) > 0, w.sum(axis=1), 1e-12)
    mu = (w @ cols[0]) / sw
    dev = cols - mu[:, None]
    var = (w * dev**2).sum(axis=1) / sw
    mu3 = (w * dev**3).sum(axis=1) / sw
    s_lo, s_hi, _ = linear_density_segment(mu, var - sigma**2, mu3)
    # The moments start a least-squares fit (robust to noise far from the streak).
    sel = np.flatnonzero(short & (sw > 1e-9))
    level = np.zeros(N)
    if sel.size:
        # Each row's window, gathered into a compact matrix (windows are short, rows long).
        first = np.floor(lo[sel]).astype(np.int64)
        width = int(np.max(np.ceil(hi[sel]).astype(np.int64) - first)) + 1
        cols_c = np.minimum(first[:, None] + np.arange(width)[None, :], A.shape[1] - 1)
        y = np.take_along_axis(A[sel] - base[sel, None], cols_c, axis=1)
        w_c = np.take_along_axis(inside[sel], cols_c, axis=1).astype(np.float64)
        a_fit, L_fit, c0 = fit_short(
            y * w_c, w_c, sigma[sel], s_lo[sel] - first, s_hi[sel] - s_lo[sel]
        )
        has = np.flatnonzero(lawful[sel])
        if law is not None and has.size:
            a_fit[has], L_fit[has], c0[has] = fit_law(
                y[has] * w_c[has],
                w_c[has],
                sigma[sel][has],
                law[sel][has],
                a_fit[has],
                L_fit[has],
            )
        s_lo[sel], s_hi[sel], level[sel] = a_fit + first, a_fit + first + L_fit, c0
    pos_a = np.where(short, s_lo, pa)
    pos_b = np.where(short, s_hi, pb)
    swap = pos_b < pos_a
    mid = 0.5 * (pos_a + pos_b)
    pos_a = np.where(swap, mid, pos_a)
    pos_b = np.where(swap, mid, pos_b)
    valid = np.where(short, has_lo & has_hi & (w.sum(axis=1) > 0), oka & okb) & (peak > 0)
    return EdgeFit(
        pos_a=pos_a,
        pos_b=pos_b,
        plateau_a=np.where(short, level, Pa),
        plateau_b=np.where(short, level, Pb),
        short=short,
        # An endpoint must lie on the sampled (extended) line; anything else is a failed fit.
        valid=valid
        & np.isfinite(pos_a)
        & np.isfinite(pos_b)
        & (N > 0)
        & (pos_a >= 0)
        & (pos_b <= lens - 1)
        & (pos_b >= pos_a),
    )


def clipped_integral(a: np.ndarray, saturation: float, sigma: float) -> np.ndarray:
    """Cross-section integral of a Gaussian line ``a g(o)`` (``g`` of sigma ``sigma``, unit
    integral) clipped at ``saturation``: ``J(a) = 2 o* S + 2 a Phi(-o* / sigma)`` where the
    line is clipped (``|o| < o*``), else ``a``."""
    g0 = 1.0 / (sigma * np.sqrt(2 * np.pi))
    ratio = np.maximum(a * g0 / saturation, 1.0)
    o_star = sigma * np.sqrt(2.0 * np.log(ratio))
    return np.where(ratio > 1.0, 2 * o_star * saturation + 2 * a * normal_cdf(-o_star / sigma), a)


def unclip_profiles(A: np.ndarray, saturation: float, sigma: float) -> np.ndarray:
    """Undo saturation on cross-section integrals: invert :func:`clipped_integral` (monotone)
    by table lookup. Rows of ``A`` are profiles measured on a frame clipped at
    ``saturation`` (signal units); ``sigma`` is the raw cross-section sigma."""
    g0 = 1.0 / (sigma * np.sqrt(2 * np.pi))
    a_knee = saturation / g0
    a = a_knee * np.exp(np.linspace(0.0, 12.0, 400))
    J = clipped_integral(a, saturation, sigma)
    return np.where(a_knee < A, np.interp(A, J, a), A)
