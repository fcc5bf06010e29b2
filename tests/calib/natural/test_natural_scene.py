"""Scene clusters of natural-scene tracks (calib.natural.scene): a scene point's tracks in
different frame pairs land in one cell (the fit's own model carries the points); the
cluster-robust variance recovers a known per-cluster error and, as a negative control, adds
nothing when the errors are independent."""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.rotation import so3_exp
from calib.data import StreakSet
from calib.grid import GridEvaluator
from calib.natural.scene import cells_of, cluster_meat, scene_cells, scene_pixels
from calib.params import theta_from

W, H = 640, 360
R_CAM_IMU = so3_exp(np.array([0.1, -0.2, 0.05]))
CALIB = Calibration(
    Camera((W, H), (500.0, 505.0, 322.0, 178.0), readout_s=0.02),
    R_cam_imu=R_CAM_IMU,
    timeshift_cam_imu_s=0.004,
    gyro_bias_radps=np.array([0.01, -0.02, 0.005]),
)
FRAMES, PERIOD, EXPOSURE = 60, 1 / 30, 0.01


def _gyro() -> GyroTrace:
    """Two seconds of shake (a few degrees, camera frame) as an IMU with bias would log it."""
    t = np.arange(0.0, FRAMES * PERIOD + 0.2, 1 / 400) - 0.1
    w_cam = np.stack(
        [0.4 * np.sin(2 * np.pi * 1.3 * t), 0.5 * np.cos(2 * np.pi * 0.9 * t), 0.2 * np.sin(5 * t)],
        axis=1,
    )
    return GyroTrace(t, w_cam @ R_CAM_IMU + CALIB.gyro_bias_radps, 0.01)


def _streaks(start: np.ndarray, end: np.ndarray, frame: np.ndarray) -> StreakSet:
    ft = frame * PERIOD + EXPOSURE / 2
    return StreakSet(
        start=start,
        end=end,
        frame_t_s=ft,
        exposure_s=np.full(len(frame), PERIOD),
        frame=frame,
        streak_id=np.arange(len(frame)),
        t0_s=0.0,
        time_row=np.stack([start[:, 1], end[:, 1]], axis=1),
    )


def test_a_scene_point_keeps_its_scene_pixel_across_pairs() -> None:
    gyro = _gyro()
    rng = np.random.default_rng(3)
    n = 400
    frame = rng.integers(0, FRAMES - 1, n)
    p = np.stack([rng.uniform(40, W - 40, n), rng.uniform(40, H - 40, n)], axis=1)
    ev = GridEvaluator(gyro, R_CAM_IMU, CALIB.camera.dist, H)
    # the fit's model carries each point into the next frame (rows dated at the start point)
    moved = p + ev.residual(theta_from(CALIB), _streaks(p, p, frame))[:, :2]
    motion = np.linalg.norm(moved - p, axis=1)
    assert np.median(motion) > 5.0  # the shake moves the image
    here = scene_pixels(_streaks(p, p, frame), gyro, CALIB)
    # the same scene points as seen from the next frame, at the times the model used
    nxt = StreakSet(
        start=moved,
        end=moved,
        frame_t_s=frame * PERIOD + EXPOSURE / 2 + PERIOD,
        exposure_s=np.full(n, PERIOD),
        frame=frame + 1,
        streak_id=np.arange(n),
        t0_s=0.0,
        time_row=np.stack([p[:, 1], p[:, 1]], axis=1),  # dated as the model dated the end
    )
    there = scene_pixels(nxt, gyro, CALIB)
    gap = np.linalg.norm(here - there, axis=1)
    # measured: 0.07 px median, 0.12 px at most, against 8 px of motion (half a degree)
    assert np.median(gap) < 0.2 and gap.max() < 0.3
    # and the view of the first sample is not the frames' own (the camera turned since)
    assert np.median(np.linalg.norm(here - p, axis=1)) > 5.0


def test_scene_cells_group_by_cell() -> None:
    gyro = _gyro()
    p = np.array([[100.0, 100.0], [104.0, 102.0], [400.0, 250.0]])
    s = _streaks(p, p, np.array([3, 3, 3]))
    c = scene_cells(s, gyro, CALIB)
    assert c[0] == c[1] != c[2]
    assert cells_of(np.array([[-1.0, 0.0], [0.0, 0.0], [0.0, 64.0]])).tolist() == [0, 1, 3]


def _sandwich_var(r: np.ndarray, cluster: np.ndarray) -> float:
    """Cluster-robust variance of the least-squares mean (the model ``y = β + e``)."""
    J = np.ones((len(r), 1, 1))
    A = float(len(r))
    return float(cluster_meat(J, r[:, None], np.ones(len(r)), cluster)[0, 0]) / A**2


def test_cluster_variance_recovers_a_shared_error_and_adds_nothing_without_one() -> None:
    rng = np.random.default_rng(7)
    C, m, sigma, tau = 300, 40, 1.0, 0.3
    cluster = np.repeat(np.arange(C), m)
    # known value: every cluster shares an error of sd tau; var(mean) = (sigma²/m + tau²)/C
    truth = (sigma**2 / m + tau**2) / C
    ratios, plain_ratio, neg = [], [], []
    for _ in range(20):
        e = rng.normal(0, sigma, C * m) + np.repeat(rng.normal(0, tau, C), m)
        r = e - e.mean()
        ratios.append(_sandwich_var(r, cluster) / truth)
        plain_ratio.append(float(np.var(r)) / (C * m) / truth)
        # negative control: independent errors, the same clusters
        e0 = rng.normal(0, sigma, C * m)
        r0 = e0 - e0.mean()
        neg.append(_sandwich_var(r0, cluster) / (float(np.var(r0)) / (C * m)))
    assert abs(np.mean(ratios) - 1.0) < 0.05  # measured 1.00
    assert np.mean(plain_ratio) < 0.25  # the plain variance misses the shared error (0.20)
    assert abs(np.mean(neg) - 1.0) < 0.05  # no inflation when nothing is shared (1.00)
