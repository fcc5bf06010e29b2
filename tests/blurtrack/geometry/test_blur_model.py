"""Known-value and property tests of the blur model (blurtrack.geometry.kernels / trajectory)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blurtrack.errors import CoverageError, GeometryError
from blurtrack.geometry.blur_model import BlurModel, _grid, _upsample
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import distort, relative_rotation, undistort
from blurtrack.geometry.rotation import so3_exp, so3_log

CAM = Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5))


def constant_trace(omega: tuple[float, float, float], t_end: float = 1.0) -> GyroTrace:
    t = np.arange(0.0, t_end, 0.005)
    return GyroTrace(t, np.tile(np.asarray(omega, float), (t.size, 1)))


def model(omega, camera: Camera = CAM, **calib) -> BlurModel:
    return BlurModel(Calibration(camera, **calib), constant_trace(omega))


def grid_pixels(n: int = 7) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(50, 1230, n), np.linspace(40, 680, n))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def test_zero_rotation_gives_zero_motion() -> None:
    m = model((0.0, 0.0, 0.0))
    px = grid_pixels()
    np.testing.assert_allclose(m.warp(px, 0.2, 0.5), px, atol=1e-12)


def test_roll_moves_points_on_circles_around_principal_point() -> None:
    w = 1.5
    m = model((0.0, 0.0, w))
    px = grid_pixels()
    out = m.warp(px, 0.1, 0.3)
    c = np.array(CAM.intrinsics[2:])
    np.testing.assert_allclose(
        np.linalg.norm(out - c, axis=1), np.linalg.norm(px - c, axis=1), rtol=1e-12
    )
    ang = np.arctan2(*(out - c).T[::-1]) - np.arctan2(*(px - c).T[::-1])
    # The camera rolls by +w*dt about +z, so the scene turns by -w*dt in the image.
    np.testing.assert_allclose(np.angle(np.exp(1j * ang)), -w * 0.2, atol=1e-9)


def test_sign_convention_hand_computed() -> None:
    # Camera yaws right (+y axis, x right / y down / z forward): static scene moves left.
    m = model((0.0, 0.5, 0.0))
    centre = np.array([[639.5, 359.5]])
    out = m.warp(centre, 0.0, 0.2)
    np.testing.assert_allclose(out, [[639.5 - 1000.0 * np.tan(0.1), 359.5]], atol=1e-9)
    # Tilt about +x (camera looks down): the scene moves up... in y-down pixels, +v.
    m = model((0.5, 0.0, 0.0))
    out = m.warp(centre, 0.0, 0.2)
    np.testing.assert_allclose(out, [[639.5, 359.5 + 1000.0 * np.tan(0.1)]], atol=1e-9)


def test_small_angle_limit() -> None:
    w = np.array([0.003, -0.002, 0.001])
    m = model(tuple(w))
    px = grid_pixels()
    dt = 0.01
    out = m.warp(px, 0.0, dt)
    th = w * dt
    x = (px - CAM.intrinsics[2:]) / 1000.0
    # First-order image motion of a rotation (the classic rotational flow field).
    du = 1000.0 * (x[:, 0] * x[:, 1] * th[0] - (1 + x[:, 0] ** 2) * th[1] + x[:, 1] * th[2])
    dv = 1000.0 * ((1 + x[:, 1] ** 2) * th[0] - x[:, 0] * x[:, 1] * th[1] - x[:, 0] * th[2])
    np.testing.assert_allclose(out - px, -np.stack([du, dv], 1) * -1, atol=2e-4)


def test_homography_agrees_with_pointwise_projection() -> None:
    t = np.arange(0, 1, 0.005)
    rng = np.random.default_rng(1)
    w = np.cumsum(rng.normal(0, 0.2, (t.size, 3)), axis=0)
    m = BlurModel(Calibration(CAM), GyroTrace(t, w))
    R = m.rotations(np.array([0.3]), np.array([0.33]))[0]
    H = CAM.K @ R.T @ np.linalg.inv(CAM.K)
    px = grid_pixels()
    ph = np.c_[px, np.ones(len(px))] @ H.T
    np.testing.assert_allclose(m.warp(px, 0.3, 0.33), ph[:, :2] / ph[:, 2:], atol=1e-9)


def test_exact_integration_matches_closed_form_for_fixed_axis() -> None:
    # ω(t) = a(t) * axis: the rotation is exp(axis * ∫a) exactly.
    axis = np.array([1.0, 2.0, -2.0]) / 3.0

    def omega(t):
        a = 3.0 * np.sin(20 * t)
        return axis[0] * a, axis[1] * a, axis[2] * a

    t0, t1 = np.array([0.1]), np.array([0.25])
    R = np.stack(relative_rotation(t0, t1, omega, 4000), -1).reshape(3, 3)
    angle = 3.0 / 20 * (np.cos(20 * 0.1) - np.cos(20 * 0.25))
    np.testing.assert_allclose(R, so3_exp(axis * angle), atol=1e-8)


def test_integration_converges_for_time_varying_axis() -> None:
    def omega(t):
        return 2 * np.sin(9 * t), 3 * np.cos(7 * t), 1.5 * np.sin(5 * t + 1)

    t0, t1 = np.array([0.0]), np.array([0.5])
    coarse = np.stack(relative_rotation(t0, t1, omega, 500), -1).reshape(3, 3)
    fine = np.stack(relative_rotation(t0, t1, omega, 4000), -1).reshape(3, 3)
    assert np.linalg.norm(so3_log(coarse.T @ fine)) < 2e-6
    # ...while the per-axis small-angle sum is far off: the exact model matters.
    from blurtrack.geometry.kernels import relative_rotation_small_angle

    approx = np.stack(relative_rotation_small_angle(t0, t1, omega, 4000), -1).reshape(3, 3)
    assert np.linalg.norm(so3_log(approx.T @ fine)) > 1e-2


def test_rotation_helpers_match_scipy() -> None:
    rv = np.random.default_rng(0).normal(size=(200, 3))
    np.testing.assert_allclose(so3_exp(rv), Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)
    R = Rotation.from_rotvec(rv * 0.5).as_matrix()
    np.testing.assert_allclose(so3_log(R), rv * 0.5, atol=1e-10)


def test_camera_imu_rotation_bias_and_shift_enter_as_documented() -> None:
    R_cam_imu = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    bias = np.array([0.01, 0.02, 0.0])
    t = np.arange(0, 1, 0.005)
    w_imu = np.where(t[:, None] > 0.5, [0.4, 0.0, 0.0], [0.0, 0.0, 0.0]) + bias
    calib = Calibration(CAM, R_cam_imu=R_cam_imu, gyro_bias_radps=bias, timeshift_cam_imu_s=0.1)
    m = BlurModel(calib, GyroTrace(t, w_imu), gyro_upsample=1)  # a step: no spline ringing
    # IMU x maps to camera y; the step at t_imu = 0.5 happens at t_cam = 0.4.
    Rrel = m.rotations(np.array([0.42]), np.array([0.47]))[0]
    np.testing.assert_allclose(so3_log(Rrel), [0.0, 0.4 * 0.05, 0.0], atol=1e-12)
    still = m.rotations(np.array([0.1]), np.array([0.35]))[0]
    np.testing.assert_allclose(still, np.eye(3), atol=1e-12)


def test_rolling_shutter_rows_start_at_the_right_times() -> None:
    cam = Camera((640, 480), (500.0, 500.0, 319.5, 239.5), readout_s=0.024)
    np.testing.assert_allclose(
        cam.row_start_s(1.0, [0, 240, 479]), [1.0, 1.012, 1.0 + 0.024 * 479 / 480]
    )


def test_rolling_shutter_streak_endpoints_solve_the_row_time() -> None:
    cam = Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5), readout_s=0.03)
    m = model((0.6, 0.0, 0.0), camera=cam)  # vertical motion: rolling shutter matters
    px = grid_pixels(5)
    start, end, ts, te = m.streak_endpoints(px, 0.5, 0.5, 0.02)
    np.testing.assert_allclose(ts, 0.5 + 0.03 * start[:, 1] / 720, atol=1e-9)
    np.testing.assert_allclose(te, 0.5 + 0.03 * end[:, 1] / 720 + 0.02, atol=1e-9)
    np.testing.assert_allclose(m.warp(px, 0.5, ts), start, atol=1e-6)


def test_distortion_round_trip() -> None:
    dist = (-0.28, 0.07, 1e-3, -5e-4)
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-0.6, 0.6, (2, 500))
    xd, yd = distort(x, y, dist)
    xu, yu = undistort(xd, yd, dist)
    np.testing.assert_allclose(np.c_[xu, yu], np.c_[x, y], atol=1e-9)
    cam = Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5), "radtan", dist)
    px = grid_pixels()
    np.testing.assert_allclose(cam.project(cam.unproject(px)), px, atol=1e-9)


def test_heat_maps_match_point_tracks() -> None:
    cam = Camera((96, 64), (80.0, 80.0, 47.5, 31.5), readout_s=0.01)
    t = np.arange(0, 1, 0.005)
    w = np.stack([np.sin(9 * t), np.cos(7 * t), 0.5 * np.sin(3 * t)], 1) * 3
    m = BlurModel(Calibration(cam), GyroTrace(t, w))
    maps, err = m.heat_maps(0.4, 0.03, n_t=9)
    tref = m.default_reference_time(0.4, 0.03)
    x, y = 30.0, 50.0
    tr = cam.row_start_s(0.4, y)
    q0 = m.warp(np.array([[x, y]]), tr, tref)[0] - (x, y)
    q1 = m.warp(np.array([[x, y]]), tr + 0.03, tref)[0] - (x, y)
    np.testing.assert_allclose(maps[:4, 50, 30], np.r_[q0, q1], atol=1e-4)
    assert maps.dtype == np.float32 and maps.shape == (6, 64, 96)
    strided, _ = m.heat_maps(0.4, 0.03, n_t=9, stride=4)
    assert np.abs(strided - maps).max() < 0.01
    assert err.max() < 0.5


@pytest.mark.parametrize(
    ("W", "H", "stride"), [(96, 64, 4), (100, 37, 16), (50, 20, 64), (17, 9, 3)]
)
def test_strided_heat_map_upsampling_is_bilinear(W: int, H: int, stride: int) -> None:
    # a + b x + c y + d x y is bilinear in every grid cell, so interpolating it from the stride
    # grid (last row and column included) must reproduce it at every pixel.
    xs = _grid(W, stride)
    ys = _grid(H, stride)
    coef = np.array([[1.5, -0.2, 0.3, 0.004], [-3.0, 0.05, -0.1, -0.002]])

    def f(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack([a + b * x + c * y + d * x * y for a, b, c, d in coef])

    got = _upsample(f(xs[None, :], ys[:, None]), xs, ys, W, H)
    want = f(np.arange(W)[None, :], np.arange(H)[:, None])
    assert got.dtype == np.float32 and got.shape == (2, H, W)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * np.abs(want).max())


def test_coverage_is_enforced() -> None:
    m = model((0.1, 0.0, 0.0))
    with pytest.raises(CoverageError, match="gyro covers"):
        m.warp(np.array([[1.0, 2.0]]), 0.9, 1.2)
    t = np.r_[np.arange(0, 0.3, 0.005), np.arange(0.4, 1.0, 0.005)]
    gappy = BlurModel(Calibration(CAM), GyroTrace(t, np.zeros((t.size, 3))))
    with pytest.raises(CoverageError, match="gap"):
        gappy.warp(np.array([[1.0, 2.0]]), 0.28, 0.45)


def test_bad_inputs_raise_one_line_errors() -> None:
    with pytest.raises(GeometryError):
        Camera((0, 10), (1.0, 1.0, 0.0, 0.0))
    with pytest.raises(GeometryError):
        Camera((10, 10), (1.0, 1.0, 0.0, 0.0), "radtan", (0.1,))
    with pytest.raises(GeometryError, match="NaN"):
        GyroTrace(np.array([0.0, 1.0]), np.array([[0, np.nan, 0], [0, 0, 0]]))
    with pytest.raises(GeometryError, match="increasing"):
        GyroTrace(np.array([0.0, 0.0]), np.zeros((2, 3)))


def test_no_points_give_empty_predictions() -> None:
    # A frame without dots: every prediction is empty, none raises (the coverage check has
    # no time to test).
    m = model((0.6, 0.2, 0.0))
    none = np.zeros((0, 2))
    start, end, ts, te = m.streak_endpoints(none, 0.5, 0.5, 0.02)
    assert start.shape == end.shape == (0, 2) and ts.shape == te.shape == (0,)
    assert m.warp(none, np.zeros(0), np.zeros(0)).shape == (0, 2)
    assert m.point_track_ordered(none, np.zeros(0), np.zeros((0, 17))).shape == (0, 17, 2)
    # Negative control: one point outside the gyro's span still raises.
    with pytest.raises(CoverageError):
        m.streak_endpoints(np.array([[10.0, 10.0]]), 1e6, 1e6, 0.02)
