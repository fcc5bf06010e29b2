"""The grid evaluator (calib.grid) against the per-streak model, finite differences, and the
per-streak model against BlurModel under random parameters (gyro scale included)."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.blur_model import BlurModel
from calib.data import relative_gyro
from calib.grid import GridEvaluator
from calib.gridops import prefix_products
from calib.params import LAYOUT, N_THETA, apply_theta, theta_from
from calib.problem import ResidualModel
from calib.testing import make_problem
from calib.tracks import build_tracks

N_SUB = 24  # sub-steps of the per-streak model (20 ms exposure + 25 ms readout: <= 1.9 ms)


@pytest.fixture(scope="module")
def setup():
    p = make_problem(seed=4, n_frames=6, dots_per_frame=30, endpoint_noise_px=0.0, tracked=True)
    g = relative_gyro(p.gyro.upsampled(8), p.streaks.t0_s)
    return p, g


def _random_theta(p, rng) -> np.ndarray:
    th = theta_from(p.truth)
    th[LAYOUT["timeshift_s"]] += rng.uniform(-2e-3, 2e-3)
    th[LAYOUT["intrinsics"]] += rng.uniform(-5, 5, 4)
    th[LAYOUT["readout_s"]] = rng.uniform(0.01, 0.04)
    th[LAYOUT["bias"]] += rng.uniform(-0.02, 0.02, 3)
    th[LAYOUT["rotation"]] = rng.uniform(-0.02, 0.02, 3)
    th[LAYOUT["scale"]] = rng.uniform(-0.05, 0.05, 6)
    return th


def test_prefix_products_equal_sequential_products() -> None:
    rng = np.random.default_rng(0)
    from blurtrack.geometry.kernels import so3_exp_c

    steps = np.stack(so3_exp_c(*rng.normal(0, 0.3, (3, 37))))
    P = prefix_products(steps)
    R = np.eye(3)
    for k in range(37):
        R = R @ steps[:, k].reshape(3, 3)
        np.testing.assert_allclose(P[:, k + 1].reshape(3, 3), R, atol=1e-13)


def test_blur_model_equals_residual_np_for_random_theta(setup) -> None:
    # residual_np(θ) is BlurModel(apply_theta(θ)).warp of the start over the same interval:
    # one model (same sub-steps; the exact (I + S)^-1 in both).
    p, g = setup
    rng = np.random.default_rng(1)
    s = p.streaks
    model = ResidualModel(g, p.initial.R_cam_imu, (), 720, N_SUB)
    for _ in range(3):
        th = _random_theta(p, rng)
        r = model.residual_np(th, s)
        cal = apply_theta(p.initial, th)
        rows = s.rows / 720
        ro = th[LAYOUT["readout_s"]]
        t_s = s.frame_t_s + ro * rows[:, 0]
        t_e = s.frame_t_s + ro * rows[:, 1] + s.exposure_s
        span = float(np.max(t_e - t_s))
        bm = BlurModel(
            cal, g, max_substep_s=span / N_SUB * (1 + 1e-9), gyro_upsample=1, check_coverage=False
        )
        pred = bm.warp(s.start, t_s, t_e) - s.end
        assert np.max(np.abs(th[LAYOUT["scale"]])) > 0.01
        np.testing.assert_allclose(r, pred, atol=1e-9, rtol=0)


def test_grid_residual_matches_the_per_streak_model(setup) -> None:
    p, g = setup
    rng = np.random.default_rng(2)
    th = _random_theta(p, rng)
    fine = ResidualModel(g, p.initial.R_cam_imu, (), 720, 8 * N_SUB)  # 0.23 ms sub-steps
    ev = GridEvaluator(g, p.initial.R_cam_imu, (), 720)
    tracks, _ = build_tracks(fine, theta_from(p.truth), p.streaks)
    assert len(tracks) > 50
    for s in (p.streaks, tracks):
        ref = fine.residual_np(th, s)
        # Both are second-order integrators; the grid's 0.5 ms midpoint steps against the
        # reference's 0.23 ms: far below any detection noise (0.03 px).
        assert np.max(np.abs(ev.residual(th, s) - ref)) < 2e-3
        r, _ = ev.evaluate(th, s)
        np.testing.assert_allclose(r, ev.residual(th, s), atol=1e-9)


def test_grid_jacobian_matches_finite_differences(setup) -> None:
    p, g = setup
    rng = np.random.default_rng(3)
    th = _random_theta(p, rng)
    ev = GridEvaluator(g, p.initial.R_cam_imu, (), 720)
    s = p.streaks
    free = (0, 1, 3, 5, 6, 8, 9, 11, 12, 15, 17)
    _, J = ev.evaluate(th, s, free)
    assert np.all(J[:, :, [i for i in range(N_THETA) if i not in free]] == 0)
    for i in free:
        e = 1e-7 if i in (LAYOUT["timeshift_s"], LAYOUT["readout_s"]) else 1e-6
        tp, tm = th.copy(), th.copy()
        tp[i] += e
        tm[i] -= e
        fd = (ev.residual(tp, s) - ev.residual(tm, s)) / (2 * e)
        # Time derivatives take ω at the interval ends (the grid's midpoint steps are
        # piecewise constant in time): exact to the quadrature, 1e-3 relative.
        tol = 3e-3 if i in (LAYOUT["timeshift_s"], LAYOUT["readout_s"]) else 3e-4
        assert np.max(np.abs(fd - J[:, :, i])) <= tol * np.max(np.abs(fd)), i


def test_jacobian_in_chunks_equals_one_call(setup, monkeypatch) -> None:
    # The mapped Jacobian runs in chunks of MAP_CHUNK residuals, the last padded: chunking
    # must not change a single value (negative control: another theta does).
    import calib.gridops as gridops

    p, g = setup
    s = p.streaks
    th = _random_theta(p, np.random.default_rng(3))
    free = tuple(range(N_THETA))
    assert len(s) < gridops.MAP_CHUNK
    r1, J1 = GridEvaluator(g, p.initial.R_cam_imu, (), 720).evaluate(th, s, free)
    monkeypatch.setattr(gridops, "MAP_CHUNK", 37)  # several full chunks and a padded one
    assert len(s) % 37
    ev = GridEvaluator(g, p.initial.R_cam_imu, (), 720)
    r2, J2 = ev.evaluate(th, s, free)
    np.testing.assert_array_equal(r1, r2)
    np.testing.assert_array_equal(J1, J2)
    _, J3 = ev.evaluate(_random_theta(p, np.random.default_rng(4)), s, free)
    assert not np.allclose(J1, J3)


def test_chain_rule_jacobian_equals_the_full_sx_jacobian(setup) -> None:
    # evaluate() differentiates through z = (δφ, rot, K) and chains ∂δφ/∂θ in numpy; the SX
    # function of every parameter (the reference) must give the same residuals and Jacobian.
    p, g = setup
    ev = GridEvaluator(g, p.initial.R_cam_imu, (), 720)
    th = _random_theta(p, np.random.default_rng(5))
    free = (0, 1, 2, 5, 6, 7, 9, 12, 14, 16)
    for s in (p.streaks, build_tracks(ev, th, p.streaks)[0]):
        r, J = ev.evaluate(th, s, free)
        r_ref, J_ref = ev._evaluate_full(th, s, free)
        np.testing.assert_allclose(r, r_ref, atol=1e-9, rtol=0)
        scale = np.max(np.abs(J_ref), axis=(0, 1)) + 1e-300
        np.testing.assert_allclose(J / scale, J_ref / scale, atol=1e-9, rtol=0)
        assert np.all(J[:, :, 3] == 0) and np.all(J_ref[:, :, 3] == 0)  # cx held
