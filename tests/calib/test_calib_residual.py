"""The calibration residual: zero at the truth, the grid evaluator against it."""

from __future__ import annotations

import numpy as np
import pytest

from calib.data import relative_gyro
from calib.grid import GridEvaluator
from calib.params import apply_theta, theta_from
from calib.problem import ResidualModel, choose_substeps
from calib.testing import make_problem


@pytest.fixture(scope="module")
def clean():
    p = make_problem(seed=3, n_frames=8, dots_per_frame=40, endpoint_noise_px=0.0)
    g = relative_gyro(p.gyro.upsampled(8), p.streaks.t0_s)
    model = ResidualModel(g, p.truth.R_cam_imu, (), 720, choose_substeps(p.streaks, 720, 0.05))
    return p, model


def test_residual_vanishes_at_truth(clean) -> None:
    p, model = clean
    r = model.residual_np(theta_from(p.truth), p.streaks)
    assert p.streaks.length_px.mean() > 10  # the test data move
    # Same fixed point as BlurModel.streak_endpoints, up to its row-time iteration and
    # sub-step count (both converge far below detection noise).
    assert np.max(np.abs(r)) < 2e-3


def test_residual_sees_a_wrong_timeshift(clean) -> None:
    p, model = clean
    th = theta_from(p.truth)
    th[0] += 0.002
    assert np.median(np.linalg.norm(model.residual_np(th, p.streaks), axis=1)) > 0.05


def test_grid_jacobian_of_a_free_subset_and_the_per_streak_model(clean) -> None:
    # The solver's evaluator (calib.grid) on the per-streak model's data: the same residual
    # within the grid's quadrature, and a Jacobian over a subset of the parameters equal to
    # those columns of the full one, zero elsewhere (finite differences: test_calib_grid).
    p, model = clean
    sub = p.streaks.subset(np.arange(250))
    ev = GridEvaluator(model.gyro, model.R0_cam_imu, (), 720)
    dth = [1e-3, 2, -1, 3, -2, 1e-3, 1e-3, -1e-3, 2e-3, 1e-3, -2e-3, 3e-3, 2e-3, -1e-3]
    th = theta_from(p.truth) + np.array([*dth, 1e-3, 5e-4, -5e-4, 1e-3])
    r, J = ev.evaluate(th, sub)
    _, J_part = ev.evaluate(th, sub, (0, 5, 13))
    np.testing.assert_allclose(J_part[:, :, [0, 5, 13]], J[:, :, [0, 5, 13]], rtol=1e-12)
    assert np.all(J_part[:, :, 1] == 0) and np.all(J[:, :, 1] != 0)
    ref = model.residual_np(th, sub)
    assert np.max(np.abs(r - ref)) < 3e-3
    assert np.median(np.abs(ref)) > 0.1  # the parameters are off: the residuals are not small


def test_apply_theta_round_trip(clean) -> None:
    p, _ = clean
    th = theta_from(p.initial)
    th[9:12] = [0.01, -0.02, 0.03]
    c = apply_theta(p.initial, th)
    back = theta_from(c)
    np.testing.assert_allclose(back[:9], th[:9])
    assert not np.allclose(c.R_cam_imu, p.initial.R_cam_imu)
