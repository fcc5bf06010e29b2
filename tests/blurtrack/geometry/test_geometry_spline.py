"""The written-out not-a-knot spline against scipy's ``CubicSpline`` (and its own truths)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from blurtrack.errors import GeometryError
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.spline import not_a_knot_slopes, resample_cubic


@pytest.mark.parametrize("n", [4, 5, 6, 9, 200, 5000])
def test_equals_scipy_on_uneven_knots(n: int) -> None:
    rng = np.random.default_rng(n)
    t = 3.0 + np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    y = rng.normal(size=(n, 3)) * [1.0, 0.1, 5.0]
    tt, yy = resample_cubic(t, y, 8)
    ref = CubicSpline(t, y, axis=0)
    scale = np.abs(ref(t, 1)).max() * np.diff(t).max() + np.abs(y).max()
    np.testing.assert_allclose(yy, ref(tt), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(not_a_knot_slopes(t, y), ref(t, 1), rtol=1e-11, atol=0)
    np.testing.assert_array_equal(yy[::8], y)  # the knots' own values, exactly
    assert tt.size == 8 * (n - 1) + 1 and tt[-1] == t[-1]


def test_a_cubic_is_its_own_spline_and_a_sine_is_not() -> None:
    t = np.array([0.0, 0.3, 1.0, 1.1, 2.5, 4.0])
    cubic = np.stack([t**3 - 2 * t, 0.5 * t**2 + 1, np.ones_like(t)], axis=1)
    tt, yy = resample_cubic(t, cubic, 5)
    expect = np.stack([tt**3 - 2 * tt, 0.5 * tt**2 + 1, np.ones_like(tt)], axis=1)
    np.testing.assert_allclose(yy, expect, atol=1e-12)
    # Negative control: a sine through the same knots is only approximated between them.
    _, ys = resample_cubic(t, np.sin(t)[:, None], 5)
    err = np.abs(ys[:, 0] - np.sin(tt))
    assert err.max() > 1e-3 and np.all(err[::5] == 0)


def test_long_trace_is_solved_in_a_few_reduction_steps() -> None:
    # 1 kHz for 200 s: the same spline as scipy's (the reduction stops when decoupled).
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.9e-3, 1.1e-3, 200_000))
    y = np.cumsum(rng.normal(size=(t.size, 3)), axis=0) * 1e-2
    s = not_a_knot_slopes(t, y)
    np.testing.assert_allclose(s, CubicSpline(t, y, axis=0)(t, 1), rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("t", "msg"),
    [
        (np.arange(3.0), ">= 4 knots"),
        (np.array([0.0, 1.0, 1.0, 2.0]), "strictly increasing"),
        (np.array([0.0, 2.0, 1.0, 3.0]), "strictly increasing"),
    ],
)
def test_refuses_too_few_or_unordered_knots(t: np.ndarray, msg: str) -> None:
    with pytest.raises(GeometryError, match=msg):
        not_a_knot_slopes(t, np.zeros((t.size, 3)))


def test_gyro_resampling_is_scipys_spline_per_segment() -> None:
    rng = np.random.default_rng(5)
    parts = [np.arange(50) * 1e-3, 0.2 + np.arange(3) * 1e-3, 0.4 + np.arange(30) * 1e-3]
    t = np.concatenate(parts)
    w = rng.normal(size=(t.size, 3))
    up = GyroTrace(t, w, max_gap_s=0.01).upsampled(4)
    a, b = up.t_s < 0.1, up.t_s > 0.3
    ref1 = CubicSpline(t[:50], w[:50], axis=0)(up.t_s[a])
    ref2 = CubicSpline(t[53:], w[53:], axis=0)(up.t_s[b])
    np.testing.assert_allclose(up.omega_radps[a], ref1, atol=1e-12)
    np.testing.assert_allclose(up.omega_radps[b], ref2, atol=1e-12)
    mid = ~a & ~b  # three samples between the gaps: kept as they are
    np.testing.assert_array_equal(up.omega_radps[mid], w[50:53])
