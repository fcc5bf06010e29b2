"""Gyro traces (blurtrack.geometry.gyro): interpolation of the three axes."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace


def _trace(seed: int = 1) -> GyroTrace:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1e-3, 3e-3, 500))
    return GyroTrace(t, rng.normal(0.0, 2.0, (500, 3)))


@pytest.mark.parametrize("where", ["random", "samples", "edges", "scalar", "grid"])
def test_the_three_axes_are_numpys_interpolation_bit_for_bit(where: str) -> None:
    # One search for all three axes instead of np.interp's one per axis: the same values,
    # to the last bit, at and between samples, at both ends, outside (the end samples' values)
    # and for NaN; the shape of the times is kept.
    tr = _trace()
    t = tr.t_s
    rng = np.random.default_rng(2)
    x = {
        "random": rng.uniform(t[0] - 0.05, t[-1] + 0.05, 10_000),
        "samples": t.copy(),
        "edges": np.array([t[0], t[-1], np.nan, t[0] - 1.0, t[-1] + 1.0, np.nextafter(t[-1], 0)]),
        "scalar": np.array(t[3] + 1e-4),
        "grid": rng.uniform(t[0], t[-1], (7, 11)),
    }[where]
    got = tr.omega_components(x)
    stacked = tr.omega_at(x)
    for k in range(3):
        ref = np.interp(x, t, tr.omega_radps[:, k])
        assert np.shape(got[k]) == np.shape(ref)
        np.testing.assert_array_equal(got[k], ref)
        np.testing.assert_array_equal(stacked[..., k], ref)


def test_interpolation_is_linear_between_samples() -> None:
    # Known values: halfway between two samples, the mean of their rates.
    tr = GyroTrace(
        np.array([0.0, 1.0, 3.0]), np.array([[0.0, 1.0, 2.0], [2.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    )
    np.testing.assert_allclose(
        tr.omega_at(np.array([0.5, 2.0])), [[1.0, 1.0, 1.0], [1.0, 0.5, 0.0]]
    )
