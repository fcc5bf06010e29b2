"""Axis discovery on laser midpoints (calib.axes_laser) with known truth, and refusals."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace
from calib.axes import (
    AxisSearchError,
    check_axes,
    nearest_axis_permutation,
    proper_axis_permutations,
)
from calib.axes_laser import search_axes_laser
from calib.data import relative_gyro
from calib.testing import make_problem
from calib.tracks import mean_rows


@pytest.fixture(scope="module")
def problem():
    return make_problem(
        seed=3, n_frames=10, dots_per_frame=30, endpoint_noise_px=0.05, tracked=True
    )


def _search(p, gyro):
    s = p.streaks
    return search_axes_laser(
        s.mid,
        mean_rows(s),
        s.frame,
        s.frame_t_s,
        s.exposure_s,
        p.initial.camera,
        relative_gyro(gyro, s.t0_s),
        0.0,
        0.06,
    )


def test_laser_search_finds_the_true_axes_and_shift(problem) -> None:
    res = _search(problem, problem.gyro)
    check_axes(res)
    P = proper_axis_permutations()[nearest_axis_permutation(problem.truth.R_cam_imu)]
    assert np.allclose(res.R_cam_imu, P)
    assert res.margin > 5
    # The permutation is not the true (1.5 degrees misaligned) rotation: the shift is an
    # initial value for the fit, a few ms off at most.
    assert abs(res.winner.timeshift_s - problem.truth.timeshift_cam_imu_s) < 3e-3


def test_laser_search_refuses_a_foreign_gyro(problem) -> None:
    other = make_problem(seed=9, n_frames=10, dots_per_frame=30, tracked=True).gyro
    res = _search(problem, GyroTrace(other.t_s, other.omega_radps))
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        check_axes(res)
