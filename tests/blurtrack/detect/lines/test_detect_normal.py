"""The written-out normal CDF against scipy's (known values, bound, symmetry, monotonicity)."""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from blurtrack.detect.lines.normal import MAX_ABS_ERROR, normal_cdf, normal_cdf_given_exp


def test_within_the_stated_bound_of_scipy_everywhere() -> None:
    x = np.linspace(-12.0, 12.0, 480_001)
    err = np.abs(normal_cdf(x) - ndtr(x))
    assert err.max() <= MAX_ABS_ERROR
    # negative control: the bound is tight enough to catch a wrong scale (erf for Phi)
    wrong = normal_cdf(x * np.sqrt(2.0))
    assert np.abs(wrong - ndtr(x)).max() > 1e3 * MAX_ABS_ERROR


def test_exact_at_zero_symmetric_and_monotone() -> None:
    assert float(normal_cdf(0.0)) == 0.5
    x = np.linspace(0.0, 9.0, 9001)
    assert np.allclose(normal_cdf(x) + normal_cdf(-x), 1.0, rtol=0, atol=1e-15)
    assert np.all(np.diff(normal_cdf(np.linspace(-9, 9, 90001))) >= 0)
    assert normal_cdf(np.array([-40.0, 40.0])).tolist() == [0.0, 1.0]


def test_given_exp_is_the_same_function() -> None:
    u = np.array([[-2.5, -0.1], [0.3, 4.0]])
    assert np.array_equal(normal_cdf_given_exp(u, np.exp(-0.5 * u * u)), normal_cdf(u))
