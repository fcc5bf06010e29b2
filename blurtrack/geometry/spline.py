"""The not-a-knot cubic interpolating spline, written out over numpy.

Written by hand, for one measured reason: importing ``scipy.interpolate`` (for its
``CubicSpline``) costs 0.4-0.7 s of one core, which ``blurtrack detect`` pays while its
workers detect (on a dense 100-frame 720p session, a tenth of the command); the
gyro's resampling (:meth:`blurtrack.geometry.gyro.GyroTrace.upsampled`) is its only use
there. The result is scipy's spline (tested against it to 1e-12 of the data's scale).

The spline through ``(t_i, y_i)``, ``i = 0 .. n-1``, is written by its slopes ``s_i`` at the
knots (cubic Hermite pieces). With ``h_i = t_{i+1} - t_i`` and the secants
``m_i = (y_{i+1} - y_i) / h_i``, continuity of the second derivative at the inner knots gives

    h_i s_{i-1} + 2 (h_{i-1} + h_i) s_i + h_{i-1} s_{i+1} = 3 (h_i m_{i-1} + h_{i-1} m_i),

and *not-a-knot* (the third derivative continuous at ``t_1`` and ``t_{n-2}``: the first two
and the last two pieces are one cubic each) the two end rows

    h_1 s_0 + (h_0 + h_1) s_1 = ((h_0 + 2 (h_0 + h_1)) h_1 m_0 + h_0^2 m_1) / (h_0 + h_1)

and its mirror image. Subtracting each end row from its neighbour removes ``s_0`` and
``s_{n-1}`` and leaves a strictly diagonally dominant tridiagonal system in
``s_1 .. s_{n-2}``, solved by parallel cyclic reduction: each step couples every row to the
rows twice as far away as before, and the coupling (1/2 of the diagonal in the inner rows,
under 1 in the two rows next to the ends) about squares each step, so that after a handful
of steps (6 for 60 000 knots spaced 0.5-1.5 ms) it is below the rounding of the diagonal and
each row is solved alone.
"""

from __future__ import annotations

import numpy as np

from blurtrack.errors import GeometryError

#: Fewest knots (with three the not-a-knot spline is the parabola through them).
MIN_KNOTS = 4
#: Cyclic reduction stops when every row's coupling is this far below its diagonal.
DECOUPLED = 1e-18


def _cyclic_reduction(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Solve the tridiagonal system ``a_i x_{i-1} + b_i x_i + c_i x_{i+1} = d_i`` (``a_0``
    and ``c_{m-1}`` ignored), strictly diagonally dominant; ``a, b, c`` ``(m,)``, ``d``
    ``(m, k)`` (``k`` right-hand sides)."""
    m = b.size
    a, b, c = a.astype(float), b.astype(float), c.astype(float)
    dT = np.array(d, float).T.copy()  # (k, m): each right-hand side contiguous
    a[0] = 0.0
    c[-1] = 0.0
    s = 1
    while s < m:
        if float(np.max((np.abs(a) + np.abs(c)) / np.abs(b))) < DECOUPLED:
            break
        # Row i takes in rows i - s (for i >= s) and i + s (for i < m - s): a_i is zero for
        # i < s and c_i for i >= m - s (no such rows), and stays so.
        alpha = -a[s:] / b[:-s]
        gamma = -c[:-s] / b[s:]
        b_new = b.copy()
        b_new[s:] += alpha * c[:-s]
        b_new[:-s] += gamma * a[s:]
        d_new = dT.copy()
        d_new[:, s:] += alpha * dT[:, :-s]
        d_new[:, :-s] += gamma * dT[:, s:]
        a_new = np.zeros(m)
        a_new[s:] = alpha * a[:-s]
        c_new = np.zeros(m)
        c_new[:-s] = gamma * c[s:]
        a, b, c, dT = a_new, b_new, c_new, d_new
        s *= 2
    return np.asarray((dT / b).T)


def not_a_knot_slopes(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Slopes ``(n, k)`` at the knots of the not-a-knot cubic spline through ``t (n,)``
    (strictly increasing, ``n >= 4``) and ``y (n, k)``.

    >>> t = np.array([0.0, 1.0, 3.0, 4.0, 7.0])
    >>> np.round(not_a_knot_slopes(t, (t**3)[:, None])[:, 0], 9)  # a cubic is its own spline
    array([  0.,   3.,  27.,  48., 147.])
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    n = t.size
    if n < MIN_KNOTS or y.shape[0] != n:
        raise GeometryError(f"a not-a-knot spline needs >= {MIN_KNOTS} knots and one y per knot")
    h = np.diff(t)
    if not np.all(h > 0):
        raise GeometryError("spline knots must be strictly increasing")
    m = np.diff(y, axis=0) / h[:, None]
    # Rows 1 .. n-2 (inner knots).
    a = h[1:].copy()  # coefficient of s_{i-1}
    b = 2.0 * (h[:-1] + h[1:])
    c = h[:-1].copy()  # coefficient of s_{i+1}
    r = 3.0 * (h[1:, None] * m[:-1] + h[:-1, None] * m[1:])
    # End rows: b0 s_0 + c0 s_1 = r0 and a_e s_{n-2} + b_e s_{n-1} = r_e.
    d0 = h[0] + h[1]
    b0, c0 = h[1], d0
    r0 = ((h[0] + 2.0 * d0) * h[1] * m[0] + h[0] ** 2 * m[1]) / d0
    de = h[-1] + h[-2]
    a_e, b_e = de, h[-2]
    r_e = (h[-1] ** 2 * m[-2] + (2.0 * de + h[-1]) * h[-2] * m[-1]) / de
    # Row 1's s_0 coefficient (h_1) is b0 and row n-2's s_{n-1} coefficient (h_{n-3}) is
    # b_e: subtracting the end rows removes s_0 and s_{n-1}.
    b[0] -= c0
    r[0] -= r0
    b[-1] -= a_e
    r[-1] -= r_e
    inner = _cyclic_reduction(a, b, c, r)
    s0 = (r0 - c0 * inner[0]) / b0
    se = (r_e - a_e * inner[-1]) / b_e
    return np.concatenate([s0[None], inner, se[None]])


def resample_cubic(t: np.ndarray, y: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The not-a-knot spline through ``t (n,)``, ``y (n, c)`` evaluated ``k`` times per
    interval: times ``t_i + h_i j / k`` (``j = 0 .. k-1``) and the last knot,
    ``(k (n-1) + 1,)``, and the values there ``(k (n-1) + 1, c)`` (the knots' own values
    exactly).

    >>> t = np.array([0.0, 1.0, 2.0, 4.0])
    >>> tt, yy = resample_cubic(t, (t**2)[:, None], 2)
    >>> tt.tolist(), np.round(yy[:, 0], 9).tolist()
    ([0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0], [0.0, 0.25, 1.0, 2.25, 4.0, 9.0, 16.0])
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    s = not_a_knot_slopes(t, y)
    h = np.diff(t)
    f = np.arange(k) / k
    # Each piece in powers of its fraction f (Horner; f = 0 gives the knot's y exactly):
    # y_i + f h s_i + f^2 (3 dy - h (2 s_i + s_{i+1})) + f^3 (h (s_i + s_{i+1}) - 2 dy).
    dy = np.diff(y, axis=0)
    hs0, hs1 = h[:, None] * s[:-1], h[:, None] * s[1:]
    c2 = 3.0 * dy - 2.0 * hs0 - hs1
    c3 = hs0 + hs1 - 2.0 * dy
    pieces = np.empty((h.size, k, y.shape[1]))
    for j, fj in enumerate(f.tolist()):
        pieces[:, j] = y[:-1] + fj * (hs0 + fj * (c2 + fj * c3))
    tt = (t[:-1, None] + h[:, None] * f[None, :]).reshape(-1)
    return np.append(tt, t[-1]), np.concatenate([pieces.reshape(-1, y.shape[1]), y[-1:]])
