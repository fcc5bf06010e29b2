"""The calibration residual: zero at the truth, CasADi equals numpy, exact Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from calib.data import relative_gyro
from calib.jacobian import JacobianEvaluator
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


def test_casadi_residual_and_jacobian_match_numpy(clean) -> None:
    p, model = clean
    sub = p.streaks.subset(np.arange(250))  # spans two chunks, the second one padded
    ev = JacobianEvaluator(model)
    th = theta_from(p.truth) + np.array(
        [
            1e-3,
            2,
            -1,
            3,
            -2,
            1e-3,
            1e-3,
            -1e-3,
            2e-3,
            1e-3,
            -2e-3,
            3e-3,
            2e-3,
            -1e-3,
            1e-3,
            5e-4,
            -5e-4,
            1e-3,
        ]
    )
    r, J = ev.evaluate(th, sub)
    _, J_part = ev.evaluate(th, sub, (0, 5, 13))
    np.testing.assert_allclose(J_part[:, :, [0, 5, 13]], J[:, :, [0, 5, 13]], rtol=1e-12)
    assert np.all(J_part[:, :, 1] == 0)
    np.testing.assert_allclose(r, model.residual_np(th, sub), atol=1e-9, rtol=0)
    steps = np.array([1e-7, 1e-3, 1e-3, 1e-3, 1e-3, 1e-7] + [1e-6] * 12)
    for i, h in enumerate(steps):
        hi, lo = th.copy(), th.copy()
        hi[i] += h
        lo[i] -= h
        fd = (model.residual_np(hi, sub) - model.residual_np(lo, sub)) / (2 * h)
        scale = np.max(np.abs(fd)) + 1e-9
        # Linear gyro interpolation has kinks at samples: compare away from them robustly.
        close = np.abs(J[:, :, i] - fd) <= 1e-4 * scale + 1e-6
        assert np.mean(close) > 0.9, f"parameter {i}"


def test_fast_jacobian_equals_the_interpolant_graph(clean) -> None:
    """The SX evaluator's local gyro linearisation gives the ca.interpolant graph's Jacobian."""
    p, model = clean
    sub = p.streaks.subset(np.arange(40))
    th = theta_from(p.truth) + 1e-3
    _, jac = model.casadi_functions(len(sub))
    r_ref, J_ref = jac(th, model.data_matrix(sub))
    r, J = JacobianEvaluator(model).evaluate(th, sub)
    n = len(sub)
    np.testing.assert_allclose(r[:, 0], np.asarray(r_ref).ravel()[:n], atol=1e-9)
    J_ref = np.asarray(J_ref)
    scale = np.abs(J_ref).max(axis=0) + 1e-12
    np.testing.assert_allclose(J[:, 0, :] / scale, J_ref[:n] / scale, atol=1e-9)
    np.testing.assert_allclose(J[:, 1, :] / scale, J_ref[n:] / scale, atol=1e-9)


def test_apply_theta_round_trip(clean) -> None:
    p, _ = clean
    th = theta_from(p.initial)
    th[9:12] = [0.01, -0.02, 0.03]
    c = apply_theta(p.initial, th)
    back = theta_from(c)
    np.testing.assert_allclose(back[:9], th[:9])
    assert not np.allclose(c.R_cam_imu, p.initial.R_cam_imu)
