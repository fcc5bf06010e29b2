"""True motion (spline + exact integral) and the simulated gyro."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.kernels import relative_rotation
from blurtrack.geometry.rotation import so3_exp, so3_log
from rigs.sim.errors import SimError
from rigs.sim.motion import TrueMotion, cumulative_product, synthetic_omega
from rigs.sim.preset import NOMINAL_R_CAM_IMU, get_preset
from rigs.sim.rig import SimRig


def test_cumulative_product_equals_sequential_loop() -> None:
    rng = np.random.default_rng(0)
    steps = so3_exp(rng.normal(0, 0.3, (37, 3)))
    P = cumulative_product(steps)
    acc = np.eye(3)
    for k in range(37):
        acc = acc @ steps[k]
        np.testing.assert_allclose(P[k], acc, atol=1e-13)


def make_motion(seed: int = 0) -> TrueMotion:
    t, w = synthetic_omega(np.random.default_rng(seed), 2.0, (2.0, 1.5, 1.0), (1.0, 15.0))
    return TrueMotion(t + 5.0, w)


def test_orientation_is_the_exact_integral_of_omega() -> None:
    m = make_motion()
    rng = np.random.default_rng(1)
    t0 = rng.uniform(5.2, 6.7, 20)
    t1 = t0 + rng.uniform(-0.03, 0.03, 20)
    R0, R1 = m.orientation(t0), m.orientation(t1)
    rel = np.einsum("nji,njk->nik", R0, R1)  # R_c(t0)^T R_c(t1)

    def omega(t):
        w = m.omega_cam_at(t)
        return w[:, 0], w[:, 1], w[:, 2]

    ref = np.stack(relative_rotation(t0, t1, omega, 8000), axis=-1).reshape(-1, 3, 3)
    ang = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", rel, ref)), axis=1)
    assert ang.max() < 1e-9  # 1e-6 px at f = 1000 px
    # and the motion really moves (degrees within 30 ms at these rates)
    assert np.degrees(np.linalg.norm(so3_log(rel), axis=1)).max() > 1.0


def test_world_frame_is_the_mean_orientation() -> None:
    m = make_motion(2)
    t = np.linspace(m.t_begin_s, m.t_end_s, 2001)
    R = m.orientation(t)
    assert np.linalg.norm(so3_log(R).mean(axis=0)) < 0.01


def test_motion_refuses_times_outside_its_span() -> None:
    m = make_motion()
    with pytest.raises(SimError, match="covers"):
        m.orientation(np.array([m.t_end_s + 0.1]))


def test_synthetic_omega_is_deterministic_and_scaled() -> None:
    a = synthetic_omega(np.random.default_rng(4), 3.0, (0.5, 0.2, 0.1), (1.0, 8.0))[1]
    b = synthetic_omega(np.random.default_rng(4), 3.0, (0.5, 0.2, 0.1), (1.0, 8.0))[1]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(np.sqrt((a * a).mean(0)), [0.5, 0.2, 0.1], rtol=1e-9)


def gyro_rig(**changes) -> SimRig:
    p = get_preset("realistic").replace(
        motion="synthetic", width=320, height=240, focal_px=250.0, **changes
    )
    return SimRig(p, 5, 20)


def test_ideal_gyro_is_true_omega_in_imu_frame_on_imu_clock() -> None:
    rig = gyro_rig()
    g = rig.gyro_model
    t_imu = rig.gyro_times_ns()[10:40] * 1e-9
    meas = rig.sample_gyro(t_imu, noise=False)
    w_cam = rig.omega_cam_at(t_imu - g.timeshift_cam_imu_s)
    expect = (g.scale @ (g.R_cam_imu.T @ w_cam.T)).T + g.bias_radps
    np.testing.assert_allclose(meas, expect, atol=1e-12)
    # the calibration-file convention inverts it up to the scale error
    back = (rig.calibration.R_cam_imu @ (meas - rig.calibration.gyro_bias_radps).T).T
    assert np.abs(back - w_cam).max() < 0.05 * np.abs(w_cam).max()
    assert 0.005 <= abs(g.timeshift_cam_imu_s) <= 0.030
    assert 1.0 <= rig.misalignment_deg <= 2.0
    R_nom = np.array(NOMINAL_R_CAM_IMU)
    ang = np.degrees(np.linalg.norm(so3_log(R_nom.T @ g.R_cam_imu)))
    assert ang == pytest.approx(rig.misalignment_deg, abs=1e-9)


def test_gyro_noise_level_and_timestamps() -> None:
    rig = gyro_rig(gyro_scale_error=0.0)
    t_ns = rig.gyro_times_ns()
    assert np.all(np.diff(t_ns) == 5_000_000)  # 200 Hz
    shift = rig.gyro_model.timeshift_cam_imu_s
    assert t_ns[0] * 1e-9 < rig.frame_times_ns[0] * 1e-9 + shift
    assert t_ns[-1] * 1e-9 > (rig.frame_times_ns[-1] * 1e-9 + shift + 0.02 + rig.camera.readout_s)
    t = t_ns * 1e-9
    noise = rig.sample_gyro(t) - rig.sample_gyro(t, noise=False)
    assert noise.std() == pytest.approx(0.005, rel=0.15)
    assert abs(noise.mean()) < 0.002


def test_clean_gyro_is_exact() -> None:
    rig = SimRig(get_preset("clean").replace(width=320, height=240, focal_px=250.0), 1, 3)
    t = rig.gyro_times_ns() * 1e-9
    np.testing.assert_array_equal(rig.sample_gyro(t), rig.sample_gyro(t, noise=False))
    assert rig.calibration.timeshift_cam_imu_s == 0.0
    np.testing.assert_array_equal(rig.calibration.gyro_bias_radps, 0.0)
    assert np.diff(t).min() == pytest.approx(1e-3)


def test_bad_requests_fail_with_sim_error() -> None:
    with pytest.raises(SimError, match="frames"):
        SimRig(get_preset("clean"), 0, 0)
    with pytest.raises(SimError, match="seed"):
        SimRig(get_preset("clean"), -1, 2)
    with pytest.raises(SimError, match="600 s limit"):
        SimRig(get_preset("clean"), 0, 30 * 601)
