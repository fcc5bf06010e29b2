"""Frame-noise GLS weighting: limits of the prior, known values, and a fit with gyro noise."""

from __future__ import annotations

import numpy as np

from calib.fit import FitOptions, calibrate
from calib.framenoise import FrameModel
from calib.params import theta_from
from calib.testing import make_problem


def _random_problem(seed: int = 0, n: int = 60, frames: int = 6):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(n, 2, 5))
    B = rng.normal(size=(n, 2, 3))
    r = rng.normal(size=(n, 2))
    fr = np.repeat(np.arange(frames), n // frames)
    d = rng.uniform(0.5, 1.0, n)
    groups = tuple(np.flatnonzero(fr == k) for k in range(frames))
    return J, B, r, fr, d, groups


def test_tight_prior_is_ordinary_weighted_least_squares() -> None:
    J, B, r, _, d, groups = _random_problem()
    fm = FrameModel(groups, B, d, np.full(3, 1e14), 1.0)
    A, g, _, cost = fm.normal_equations(J, r, tuple(range(5)))
    np.testing.assert_allclose(A, np.einsum("n,nki,nkj->ij", d, J, J), rtol=1e-9)
    np.testing.assert_allclose(g, np.einsum("n,nki,nk->i", d, J, r), rtol=1e-9, atol=1e-9)
    assert np.isclose(cost, float(np.sum(d[:, None] * r**2)))


def test_flat_prior_removes_pure_frame_effects() -> None:
    J, B, _, fr, d, groups = _random_problem(1)
    nu = np.random.default_rng(2).normal(size=(6, 3))
    r = np.einsum("nkj,nj->nk", B, nu[fr])  # residuals made only of per-frame offsets
    fm = FrameModel(groups, B, d, np.full(3, 1e-12), 1.0)
    A, g, _, cost = fm.normal_equations(J, r, tuple(range(5)))
    assert abs(cost) < 1e-8 and np.max(np.abs(g)) < 1e-8
    assert abs(fm.cost(r)) < 1e-8
    assert np.all(np.linalg.eigvalsh(A) > 0)


def test_moment_estimate_finds_the_frame_effect_variance() -> None:
    rng = np.random.default_rng(3)
    n_f, per = 400, 20
    B = rng.normal(size=(n_f * per, 2, 3))
    fr = np.repeat(np.arange(n_f), per)
    nu = rng.normal(0, 0.2, (n_f, 3))
    r = np.einsum("nkj,nj->nk", B, nu[fr]) + rng.normal(0, 0.05, (n_f * per, 2))
    fm = FrameModel.estimate(r, B, fr, np.ones(n_f * per))
    assert abs(np.sqrt(fm.sigma2) - 0.05) < 0.005
    # Σ_ν = 0.2²; 400 frames give a 7 % standard error
    np.testing.assert_allclose(fm.sigma2 / fm.prior, 0.04, rtol=0.25)


def test_fit_with_frame_noise_under_gyro_noise() -> None:
    p = make_problem(
        seed=13,
        n_frames=16,
        dots_per_frame=40,
        endpoint_noise_px=0.0,
        gyro_noise_radps=0.005,
        shift_error_s=0.01,
        focal_error=0.02,
    )
    res = calibrate(
        p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.0, frame_noise=True)
    )
    assert res.converged and res.status in ("ok", "warning"), res.warnings
    assert "gls_prior_scale" in res.timings_s
    truth = theta_from(p.truth)
    for k, name in enumerate(("timeshift_s", "fx", "fy", "cx", "cy", "readout_s")):
        assert abs(res.values[name] - truth[k]) < 4 * res.sigma[name], name
