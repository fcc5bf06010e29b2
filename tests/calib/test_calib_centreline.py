"""Centre-line residuals: zero on the true track, CasADi equals numpy, exact Jacobian, fit."""

from __future__ import annotations

import numpy as np
import pytest

from calib.centreline import CentreGridEvaluator, associate, centre_factors, centre_residual_np
from calib.data import StreakSet, centre_points, relative_gyro
from calib.errors import CalibError
from calib.fit import FitOptions, calibrate
from calib.grid import GridEvaluator
from calib.params import theta_from
from calib.problem import ResidualModel, choose_substeps
from calib.testing import make_problem


@pytest.fixture(scope="module")
def clean():
    p = make_problem(seed=3, n_frames=6, dots_per_frame=40, endpoint_noise_px=0.0, centre_k=4)
    g = relative_gyro(p.gyro.upsampled(8), p.streaks.t0_s)
    model = ResidualModel(g, p.truth.R_cam_imu, (), 720, choose_substeps(p.streaks, 720, 0.05))
    return p, model


def _centre_ev(model: ResidualModel) -> CentreGridEvaluator:
    return CentreGridEvaluator(model.gyro, model.R0_cam_imu, (), 720, model.n_sub, 4)


def test_centre_points_resample_by_arc_length() -> None:
    pts = centre_points([[0, 0], [1, 0], [10, 0]], 4)
    np.testing.assert_allclose(pts, [[2, 0], [4, 0], [6, 0], [8, 0]])
    assert np.all(np.isnan(centre_points([[3, 3], [3, 3]], 2)))
    with pytest.raises(CalibError, match="infinite"):
        centre_points([[0, 0], [np.inf, 1]], 2)


def test_association_and_perpendicular_distance_known_values() -> None:
    # Track: an L from (0, 0) to (10, 0) to (10, 10), nodes 5 px apart.
    us = np.array([[0.0, 5.0, 10.0, 10.0, 10.0]])
    vs = np.array([[0.0, 0.0, 0.0, 5.0, 10.0]])
    centre = np.array([[[2.0, 1.0], [7.0, -2.0], [11.0, 8.0]]])
    seg = associate(us, vs, centre)
    assert seg.tolist() == [[0, 1, 3]]
    r = centre_residual_np(us, vs, centre, seg, np.ones(1))
    np.testing.assert_allclose(r, [[1.0, -2.0, -1.0]], atol=1e-6)


def test_track_ends_at_the_endpoint_residual(clean) -> None:
    # The centre evaluator's endpoint columns are the grid's endpoint residual, bit for bit
    # (the last track node is looked up at the end time itself), and within the grid's
    # accuracy of the per-streak model.
    p, model = clean
    th = theta_from(p.truth) + 1e-3
    r = _centre_ev(model).residual(th, p.streaks)
    grid = GridEvaluator(model.gyro, model.R0_cam_imu, (), 720)
    np.testing.assert_array_equal(r[:, :2], grid.residual(th, p.streaks))
    assert np.max(np.abs(r[:, :2] - model.residual_np(th, p.streaks))) < 3e-3


def test_centre_residual_vanishes_at_truth(clean) -> None:
    p, model = clean
    ev = _centre_ev(model)
    r = ev.residual(theta_from(p.truth), p.streaks)
    assert r.shape == (len(p.streaks), 6)
    used = centre_factors(p.streaks) > 0
    assert used.mean() > 0.5
    # chords of a curved 0.5 px-segment track and the model's own accuracy: far below noise
    assert np.max(np.abs(r[used, 2:])) < 5e-3
    th = theta_from(p.truth)
    th[5] += 0.005  # a wrong readout bends the predicted track
    assert np.median(np.abs(ev.residual(th, p.streaks)[used, 2:])) > 1e-3


def test_centre_jacobian_matches_numpy_and_finite_differences(clean) -> None:
    p, model = clean
    sub = p.streaks.subset(np.arange(60))
    ev = _centre_ev(model)
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
    np.testing.assert_allclose(r, ev.residual(th, sub), atol=1e-9, rtol=0)
    # Endpoint columns are those of the endpoint-only evaluator.
    grid = GridEvaluator(model.gyro, model.R0_cam_imu, (), 720)
    r0, J0 = grid.evaluate(th, sub)
    np.testing.assert_allclose(r[:, :2], r0, atol=1e-9, rtol=0)
    np.testing.assert_allclose(J[:, :2], J0, rtol=1e-9, atol=1e-12)
    steps = np.array([1e-7, 1e-3, 1e-3, 1e-3, 1e-3, 1e-7] + [1e-6] * 12)
    for i, h in enumerate(steps):
        hi, lo = th.copy(), th.copy()
        hi[i] += h
        lo[i] -= h
        fd = (ev.residual(hi, sub) - ev.residual(lo, sub)) / (2 * h)  # association held
        scale = np.max(np.abs(fd[:, 2:])) + 1e-9
        close = np.abs(J[:, 2:, i] - fd[:, 2:]) <= 1e-4 * scale + 1e-6
        assert np.mean(close) > 0.9, f"parameter {i}"


def test_centre_points_follow_start_end_swaps() -> None:
    c = np.arange(12.0).reshape(2, 3, 2)
    s = StreakSet(
        np.zeros((2, 2)),
        np.ones((2, 2)),
        np.zeros(2),
        np.full(2, 0.01),
        np.zeros(2),
        np.arange(2),
        centre=c,
    )
    np.testing.assert_array_equal(s.flipped().centre, c[:, ::-1])
    np.testing.assert_array_equal(s.reoriented(np.array([True, False])).centre[1], c[1])
    np.testing.assert_array_equal(s.reoriented(np.array([True, False])).centre[0], c[0, ::-1])
    with pytest.raises(CalibError, match="centre"):
        StreakSet(
            np.zeros((2, 2)),
            np.ones((2, 2)),
            np.zeros(2),
            np.full(2, 0.01),
            np.zeros(2),
            np.arange(2),
            centre=np.zeros((2, 3)),
        )


def test_fit_with_centre_lines_recovers_truth() -> None:
    p = make_problem(
        seed=11,
        n_frames=16,
        dots_per_frame=40,
        endpoint_noise_px=0.1,
        shift_error_s=-0.02,
        focal_error=0.04,
        centre_k=4,
        centre_noise_px=0.1,
    )
    res = calibrate(
        p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.25, centreline=True)
    )
    assert res.converged and res.status in ("ok", "warning"), res.warnings
    truth = theta_from(p.truth)
    for k, name in enumerate(("timeshift_s", "fx", "fy", "cx", "cy", "readout_s")):
        assert abs(res.values[name] - truth[k]) < 4 * res.sigma[name], name
    with pytest.raises(CalibError, match="centre"):
        no_centre = make_problem(seed=11, n_frames=4, dots_per_frame=20)
        calibrate(no_centre.streaks, no_centre.gyro, no_centre.initial, FitOptions(centreline=True))
