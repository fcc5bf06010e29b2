"""Point tracks read from the tabulated orientation against the converged kernel integration."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from blurtrack.detect.gyro import gyrocurve
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.errors import CoverageError, GeometryError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.orientation_grid import GRID_STEP_S, orientation_grid
from tests.blurtrack.geometry.test_geometry_ordered_track import (
    EXPOSURE_S,
    curve_times,
    shaking_model,
)

DIST = (-0.12, 0.03, 1e-3, -5e-4)


def _grid_track(model: BlurModel, ref: np.ndarray, t_ref: np.ndarray, times: np.ndarray):
    lo, hi = np.array([min(t_ref.min(), times.min())]), np.array([max(t_ref.max(), times.max())])
    grid = model.orientation_grid(lo, hi)
    cam = model.camera
    return grid.point_track(ref, t_ref, times, np.zeros(len(ref), int), cam.intrinsics, cam.dist)


@pytest.mark.parametrize("dist", [(), DIST])
@pytest.mark.parametrize("samples", [2, 17, 65])
def test_grid_tracks_equal_the_converged_integration(dist: tuple[float, ...], samples: int) -> None:
    """Tracks of 40 points on a hand-shake gyro (several rad/s, reversing within the
    exposure), rolling shutter: the grid's within 5e-4 px of the kernel at 2e-5 s sub-steps;
    the detection models' ordered tracks (4 ms sub-steps) miss by more (negative control)."""
    rng = np.random.default_rng(3)
    ref = rng.uniform([0, 0], [1280, 720], (40, 2))
    fine = shaking_model(2e-5, dist)
    t_ref, times = curve_times(fine, ref, samples)
    truth = fine.point_track(ref, t_ref, times)
    assert np.ptp(truth[:, :, 0], axis=1).max() > 20  # the streaks move tens of px
    model = shaking_model(4e-3, dist)
    err = np.abs(_grid_track(model, ref, t_ref, times) - truth).max()
    assert err < 5e-4
    if samples >= 17:
        ordered = model.point_track_ordered(ref, t_ref, times)
        assert np.abs(ordered - truth).max() > 4 * err


def test_constant_spin_about_the_optical_axis_turns_pixels_about_the_centre() -> None:
    """Known value: at a constant 2 rad/s about the optical axis (no distortion, principal
    point at the centre), a point ``dt`` after its reference is turned by ``-2 dt`` about the
    principal point (``R_c(t)^T`` of a body turning by ``+2 dt``), also backwards in time."""
    t = np.arange(0.0, 1.0, 1e-3)
    omega = np.tile([0.0, 0.0, 2.0], (t.size, 1))
    cam = Camera((1280, 720), (900.0, 900.0, 640.0, 360.0), "none", (), readout_s=0.0)
    model = BlurModel(
        Calibration(camera=cam, R_cam_imu=np.eye(3)), GyroTrace(t, omega), gyro_upsample=1
    )
    ref = np.array([[840.0, 360.0], [640.0, 160.0]])
    t_ref = np.array([0.5, 0.52])
    times = np.array([[0.5, 0.51, 0.53], [0.49, 0.52, 0.5]])  # any order
    got = _grid_track(model, ref, t_ref, times)
    ang = -2.0 * (times - t_ref[:, None])
    d = ref - [640.0, 360.0]
    want_x = 640.0 + d[:, 0, None] * np.cos(ang) - d[:, 1, None] * np.sin(ang)
    want_y = 360.0 + d[:, 0, None] * np.sin(ang) + d[:, 1, None] * np.cos(ang)
    np.testing.assert_allclose(got, np.stack([want_x, want_y], -1), atol=1e-9)


def test_windows_are_independent_and_each_its_own_start() -> None:
    """Two windows of different lengths in one grid give each window's tracks as a grid of
    that window alone does, bit for bit (the same steps, the same prefix products)."""
    model = shaking_model(4e-3)
    cam = model.camera
    lo, hi = np.array([0.40, 0.61]), np.array([0.46, 0.64])
    both = model.orientation_grid(lo, hi)
    ref = np.array([[100.0, 50.0], [700.0, 400.0], [1000.0, 600.0]])
    window = np.array([0, 1, 0])
    t_ref = np.array([0.42, 0.62, 0.45])
    times = np.array([[0.40, 0.43, 0.46], [0.61, 0.63, 0.64], [0.41, 0.42, 0.44]])
    got = both.point_track(ref, t_ref, times, window, cam.intrinsics, cam.dist)
    for w in (0, 1):
        alone = model.orientation_grid(lo[w : w + 1], hi[w : w + 1])
        rows = window == w
        one = alone.point_track(
            ref[rows], t_ref[rows], times[rows], np.zeros(rows.sum(), int), cam.intrinsics, ()
        )
        np.testing.assert_array_equal(got[rows], one)
    assert both.P.shape[1] == round(0.06 / GRID_STEP_S) + 1  # the longer window's steps


def test_predicted_curves_of_many_frames_in_one_call_equal_one_frame_at_a_time() -> None:
    model = shaking_model(4e-3)
    ref = np.array([[100.0, 50.0], [700.0, 400.0], [1000.0, 600.0], [300.0, 100.0]])
    ft = np.array([0.40, 0.55, 0.40, 0.55])
    joint = predict_curves(model, ref, ft, EXPOSURE_S, 17).pts
    for f in (0.40, 0.55):
        rows = ft == f
        np.testing.assert_array_equal(
            joint[rows], predict_curves(model, ref[rows], f, EXPOSURE_S, 17).pts
        )


def test_two_ends_alone_on_the_coarser_grid_are_near_the_converged_ends() -> None:
    """A streak's two ends alone (the session calibration's and the check's vectors) from
    the grid of ``TWO_END_STEP_S``, 60 dots of two frames in one call, with the rolling
    shutter: within 0.05 px of the converged ends (streaks up to 110 px); a grid of the
    detection models' 4 ms sub-steps misses by more than 0.1 (negative control)."""
    rng = np.random.default_rng(5)
    ref = rng.uniform([0, 0], [1280, 720], (60, 2))
    ft = np.where(rng.random(60) < 0.5, 0.40, 0.62)
    truth = predict_curves(shaking_model(2e-5, DIST), ref, ft, EXPOSURE_S, 2).pts
    model = shaking_model(4e-3, DIST)
    assert np.hypot(*(truth[:, 1] - truth[:, 0]).T).max() > 100
    two_ends = predict_curves(model, ref, ft, EXPOSURE_S, 2).pts
    assert np.abs(two_ends - truth).max() < 0.05
    # The default grid of two ends alone is TWO_END_STEP_S's.
    explicit = predict_curves(model, ref, ft, EXPOSURE_S, 2, step_s=gyrocurve.TWO_END_STEP_S).pts
    np.testing.assert_array_equal(two_ends, explicit)
    coarse = predict_curves(model, ref, ft, EXPOSURE_S, 2, step_s=4e-3).pts
    assert np.abs(coarse - truth).max() > 0.1


def test_refusals() -> None:
    model = shaking_model(4e-3)
    with pytest.raises(GeometryError, match="not before"):
        orientation_grid(np.array([0.5]), np.array([0.4]), model.omega_cam_at)
    with pytest.raises(GeometryError, match="non-empty"):
        orientation_grid(np.zeros(0), np.zeros(0), model.omega_cam_at)
    with pytest.raises(CoverageError):
        model.orientation_grid(np.array([0.98]), np.array([1.2]))
    small = dataclasses.replace(model, rotation_model="small_angle", gyro_upsample=1)
    with pytest.raises(GeometryError, match="small_angle"):
        small.orientation_grid(np.array([0.4]), np.array([0.45]))
