"""Point tracks integrated sample to sample against the kernel's integration from the reference."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.blur_model import ORDERED_MIN_SAMPLES, BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.ordered_track import ordered_point_track

EXPOSURE_S = 0.04


def shaking_model(max_substep_s: float, dist: tuple[float, ...] = ()) -> BlurModel:
    """A hand-shake-like gyro (several rad/s, reversing within an exposure), rolling shutter."""
    t = np.arange(0.0, 1.0, 1e-3)
    omega = np.stack(
        [
            3.0 * np.sin(2 * np.pi * 7 * t),
            -2.0 * np.cos(2 * np.pi * 11 * t + 0.3),
            1.5 * np.sin(2 * np.pi * 5 * t + 1.0),
        ],
        axis=1,
    )
    cam = Camera(
        (1280, 720),
        (900.0, 905.0, 640.0, 360.0),
        "radtan" if dist else "none",
        dist,
        readout_s=0.03,
    )
    calib = Calibration(camera=cam, R_cam_imu=np.eye(3), timeshift_cam_imu_s=0.002)
    return BlurModel(calib, GyroTrace(t, omega), max_substep_s=max_substep_s, gyro_upsample=1)


def curve_times(model: BlurModel, ref: np.ndarray, samples: int) -> tuple[np.ndarray, np.ndarray]:
    row_t = 0.4 + model.camera.readout_s * ref[:, 1] / model.camera.height
    return row_t + EXPOSURE_S / 2, row_t[:, None] + EXPOSURE_S * np.linspace(0, 1, samples)


@pytest.mark.parametrize("dist", [(), (-0.12, 0.03, 1e-3, -5e-4)])
@pytest.mark.parametrize("samples", [2, 3, 65])
def test_ordered_tracks_equal_the_kernels_integration(
    dist: tuple[float, ...], samples: int
) -> None:
    rng = np.random.default_rng(3)
    ref = rng.uniform([0, 0], [1280, 720], (40, 2))
    fine = shaking_model(2e-5, dist)  # the kernel, converged
    t_ref, times = curve_times(fine, ref, samples)
    truth = fine.point_track(ref, t_ref, times)
    model = shaking_model(4e-3, dist)
    cam = model.camera
    ordered = ordered_point_track(
        ref, t_ref, times, model.omega_cam_at, cam.intrinsics, cam.dist, model.max_substep_s
    )
    kernel = model.point_track(ref, t_ref, times)
    if samples >= ORDERED_MIN_SAMPLES:
        np.testing.assert_array_equal(model.point_track_ordered(ref, t_ref, times), ordered)
    else:  # a few samples: the kernel's integration, exactly
        np.testing.assert_array_equal(model.point_track_ordered(ref, t_ref, times), kernel)
    # the streaks move tens of px; sample to sample the integration is closer to the truth
    assert np.ptp(truth[:, :, 0], axis=1).max() > 20
    err, kernel_err = np.abs(ordered - truth).max(), np.abs(kernel - truth).max()
    assert err <= kernel_err + 1e-9
    if samples == 65:  # sub-steps of the samples' 0.6 ms spacing
        assert err < 0.01 < kernel_err
    # at the reference time the track is the pixel itself
    at_ref = shaking_model(4e-3, dist).point_track_ordered(ref, t_ref, t_ref[:, None])
    np.testing.assert_allclose(at_ref[:, 0], ref, atol=1e-9)


def test_the_reference_anywhere_along_or_outside_the_samples() -> None:
    model, fine = shaking_model(1e-3), shaking_model(2e-5)
    ref = np.array([[100.0, 50.0], [640.0, 360.0], [1200.0, 700.0]])
    times = 0.4 + np.linspace(0, EXPOSURE_S, 9)[None, :].repeat(3, axis=0)
    t_ref = np.array([0.39, 0.4 + EXPOSURE_S / 3, 0.45])  # before, inside, after
    got = model.point_track_ordered(ref, t_ref, times)
    np.testing.assert_allclose(got, fine.point_track(ref, t_ref, times), atol=0.01)


def test_times_out_of_order_are_refused_and_the_model_falls_back() -> None:
    model = shaking_model(1e-3)
    ref = np.array([[300.0, 200.0]])
    times = np.array([[0.41, 0.40, 0.42]])
    cam = model.camera
    with pytest.raises(ValueError, match="do not decrease"):
        ordered_point_track(
            ref, np.array([0.41]), times, model.omega_cam_at, cam.intrinsics, cam.dist, 1e-3
        )
    np.testing.assert_array_equal(
        model.point_track_ordered(ref, np.array([0.41]), times),
        model.point_track(ref, np.array([0.41]), times),
    )
