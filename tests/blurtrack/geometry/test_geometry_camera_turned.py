"""A camera turned by 180 degrees (a sensor that reads its bottom row first, stored turned)."""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.camera import TURN_180, Camera, turned_camera


def test_a_turned_camera_sees_each_point_at_the_turned_pixel() -> None:
    cam = Camera(
        resolution=(640, 480),
        intrinsics=(500.0, 510.0, 300.0, 250.0),
        distortion_model="radtan",
        distortion_coeffs=(-0.1, 0.02, 0.001, -0.002),
        readout_s=0.02,
    )
    turned = turned_camera(cam)
    assert turned.intrinsics == (500.0, 510.0, 339.0, 229.0)
    assert turned.distortion_coeffs == (-0.1, 0.02, -0.001, 0.002)
    assert turned.readout_s == cam.readout_s
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(1.0, 3.0, 20)])
    np.testing.assert_allclose(
        turned.project(X @ TURN_180.T), [639.0, 479.0] - cam.project(X), atol=1e-9
    )
    assert turned_camera(turned) == cam
    # Negative control: the tangential terms are what the turn must negate.
    kept = Camera(
        resolution=(640, 480),
        intrinsics=turned.intrinsics,
        distortion_model="radtan",
        distortion_coeffs=cam.distortion_coeffs,
    )
    assert np.max(np.abs(kept.project(X @ TURN_180.T) - ([639.0, 479.0] - cam.project(X)))) > 0.01
