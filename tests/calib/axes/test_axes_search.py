"""Axis discovery (calib.axes.search): the 24 proper permutations, the search on simulated
motion with known truth, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.rotation import so3_exp
from calib.axes.rotations import ImageRotations
from calib.axes.search import (
    check_axes,
    nearest_axis_permutation,
    proper_axis_permutations,
    search_axes,
)
from calib.errors import AxisSearchError
from rigs.sim.preset import NOMINAL_R_CAM_IMU, get_preset
from rigs.sim.rig import SimRig


def test_permutations_are_the_24_distinct_proper_ones() -> None:
    P = proper_axis_permutations()
    assert P.shape == (24, 3, 3)
    assert np.allclose(np.linalg.det(P), 1.0)
    assert np.allclose(np.einsum("kji,kjl->kil", P, P), np.eye(3))
    assert len({p.tobytes() for p in P}) == 24
    R = so3_exp(np.array([0.02, -0.01, 0.03])) @ np.array(NOMINAL_R_CAM_IMU)
    assert np.allclose(P[nearest_axis_permutation(R)], NOMINAL_R_CAM_IMU)


def _sim(seed: int, frames: int = 30):
    rig = SimRig(get_preset("realistic"), seed, frames)
    t = rig.frame_times_ns * 1e-9
    exp = rig.preset.exposure_s
    mid = rig.camera.readout_s / 2 + exp / 2
    ta, tb = t[:-1] + mid, t[1:] + mid
    Ra, Rb = rig.motion.orientation(ta), rig.motion.orientation(tb)
    R_img = np.einsum("kji,kjl->kil", Rb, Ra)  # R_c(t_b)^T R_c(t_a)
    rng = np.random.default_rng(seed)
    R_img = so3_exp(rng.normal(0, 2e-4, (ta.size, 3))) @ R_img  # registration noise
    rots = ImageRotations(ta, tb, R_img, np.full(ta.size, 100), np.arange(ta.size))
    ti = rig.gyro_times_ns() * 1e-9
    gyro = GyroTrace(ti, rig.sample_gyro(ti))
    return rig, rots, gyro


@pytest.mark.parametrize("seed", [0, 3])
def test_search_finds_the_true_axes_and_offset(seed: int) -> None:
    rig, rots, gyro = _sim(seed)
    fx = rig.camera.intrinsics[0]
    res = search_axes(rots, gyro, fx, 0.0, 0.06, "test")
    check_axes(res)
    assert np.allclose(res.R_cam_imu, NOMINAL_R_CAM_IMU)
    assert res.margin > 3
    assert abs(res.winner.timeshift_s - rig.calibration.timeshift_cam_imu_s) < 2e-3
    d = res.to_dict()
    assert len(d["candidates"]) == 24 and d["winner"]["score_px"] == res.winner.score_px


def test_wrong_gyro_is_refused() -> None:
    rig, rots, _ = _sim(0)
    _, _, other = _sim(7)  # another recording's gyro, same clock
    res = search_axes(rots, other, rig.camera.intrinsics[0], 0.0, 0.06, "test")
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        check_axes(res)


def test_no_rotation_and_no_coverage_are_refused() -> None:
    rig, rots, gyro = _sim(0)
    still = ImageRotations(
        rots.t_a_s,
        rots.t_b_s,
        np.broadcast_to(np.eye(3), rots.R_img.shape),
        rots.n_points,
        rots.frame_a,
    )
    quiet = GyroTrace(gyro.t_s, gyro.omega_radps * 1e-4)
    res = search_axes(still, quiet, rig.camera.intrinsics[0], 0.0, 0.06, "test")
    with pytest.raises(AxisSearchError, match="no rotation"):
        check_axes(res)
    late = GyroTrace(gyro.t_s + 100.0, gyro.omega_radps)
    with pytest.raises(AxisSearchError, match="does not cover"):
        search_axes(rots, late, rig.camera.intrinsics[0], 0.0, 0.06, "test")


def test_discover_axes_refuses_an_undecided_search_unless_told_not_to() -> None:
    """``strict=False`` (diagnostics that write nothing, bench/mars_readout.py) returns the
    winner of a search ``check_axes`` refuses; the default refuses it."""
    from calib.natural.pipeline import discover_axes

    rig, rots, _ = _sim(0)
    _, _, other = _sim(7)
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        discover_axes(rots, other, 0.0, rig.calibration, 0.06, "test")
    search, start = discover_axes(rots, other, 0.0, rig.calibration, 0.06, "test", strict=False)
    assert np.allclose(start.R_cam_imu, search.R_cam_imu)
    assert start.timeshift_cam_imu_s == search.winner.timeshift_s
    # the true gyro passes either way, with the true axes
    _, start = discover_axes(rots, _sim(0)[2], 0.0, rig.calibration, 0.06, "test")
    assert np.allclose(start.R_cam_imu, NOMINAL_R_CAM_IMU)
