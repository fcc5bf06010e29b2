"""The common-heading axis search on a simulated drive: near and far points, forward travel,
small rotations, a dashboard rigid with the camera and a vehicle moving on its own."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from calib.axes.heading import epipolar_distance, fit_heading, search_axes_heading
from calib.axes.rotations import rotations_from_pairs
from calib.axes.search import check_axes, gyro_rotations, proper_axis_permutations, search_axes
from calib.axes.translation import fit_rotation_translating
from calib.errors import AxisSearchError

CAM = Camera((800, 600), (575.0, 575.0, 400.0, 300.0))
FPS = 30.0
N_FRAMES = 40
EXPOSURE_S = 0.005
P_TRUE = 11  # a signed permutation with every axis moved


def _gyro(seed: int) -> GyroTrace:
    """Smooth hand-held-like shake on the IMU clock, 0.05-0.15 rad/s per axis, 400 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(-0.2, N_FRAMES / FPS + 0.2, 1 / 400)
    w = np.zeros((t.size, 3))
    for k in range(3):
        for _ in range(3):
            f, ph, a = rng.uniform(0.3, 3.0), rng.uniform(0, 2 * np.pi), rng.uniform(0.02, 0.05)
            w[:, k] += a * np.sin(2 * np.pi * f * t + ph)
    return GyroTrace(t, w)


def _drive(
    gyro: GyroTrace,
    heading: np.ndarray,
    seed: int = 0,
    dashboard: int = 0,
    vehicle: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tracks of a camera on a car (10 m/s along ``heading`` in the camera frame) turned by
    the gyro through ``P_TRUE``: (pts_a, pts_b, pair, frame times)."""
    rng = np.random.default_rng(seed)
    P = proper_axis_permutations()[P_TRUE]
    t_frames = np.arange(N_FRAMES) / FPS
    t_obs = t_frames + EXPOSURE_S / 2
    g = gyro.upsampled(GYRO_UPSAMPLE)
    R = [np.eye(3)]  # camera-to-world orientation at each frame
    for k in range(1, N_FRAMES):
        M = gyro_rotations(g, t_obs[k - 1 : k], t_obs[k : k + 1], 0.0)[0]
        R.append(R[-1] @ P @ M @ P.T)
    pos = [np.zeros(3)]
    for k in range(1, N_FRAMES):
        pos.append(pos[-1] + R[k - 1] @ heading * 10.0 / FPS)
    # points: depths 6-80 m in the view cone
    n = 3000
    z = rng.uniform(6.0, 80.0, n)
    pix = rng.uniform([0, 0], [800, 420], (n, 2))
    X = CAM.unproject(pix) * z[:, None] / CAM.unproject(pix)[:, 2:3]
    pa, pb, pair = [], [], []
    for k in range(N_FRAMES - 1):
        xa = (X - pos[k]) @ R[k]
        xb = (X - pos[k + 1]) @ R[k + 1]
        ok = (xa[:, 2] > 1) & (xb[:, 2] > 1)
        ua, ub = CAM.project(xa[ok]), CAM.project(xb[ok])
        inside = np.all((ua > 0) & (ua < [800, 600]) & (ub > 0) & (ub < [800, 600]), axis=1)
        sel = rng.permutation(np.flatnonzero(inside))[:120]
        a, b = ua[sel], ub[sel]
        if dashboard:  # rigid with the camera: the same pixel in both frames
            d = rng.uniform([0, 450], [800, 600], (dashboard, 2))
            a, b = np.r_[a, d], np.r_[b, d]
        if vehicle:  # a car ahead keeping pace: moves 3 px sideways per frame
            v = rng.uniform([250, 250], [450, 400], (vehicle, 2))
            a, b = np.r_[a, v], np.r_[b, v + np.array([3.0, 0.0])]
        pa.append(a + rng.normal(0, 0.05, a.shape))
        pb.append(b + rng.normal(0, 0.05, b.shape))
        pair.append(np.full(len(a), k))
    return np.concatenate(pa), np.concatenate(pb), np.concatenate(pair), t_frames


HEADING = np.array([0.06, 0.02, 1.0]) / np.linalg.norm([0.06, 0.02, 1.0])


def _search(gyro_used: GyroTrace, tracks: tuple, window_s: float = 0.02):
    pa, pb, pair, t = tracks
    e = np.full(t.size, EXPOSURE_S)
    return search_axes_heading(
        pa, pb, pair, t, e, CAM, gyro_used.upsampled(GYRO_UPSAMPLE), 0.0, window_s, 3.0
    )


def test_epipolar_distance_is_the_sine_of_the_angle_off_the_circle() -> None:
    a = np.array([[0.0, 0.0, 1.0]])
    off = np.array([[np.sin(0.01), 0.0, np.cos(0.01)]])  # 0.01 rad off the y-z circle
    assert epipolar_distance(a, off, np.array([0.0, 1.0, 0.0]))[0] == pytest.approx(np.sin(0.01))


def test_fit_heading_recovers_the_direction_of_travel() -> None:
    rng = np.random.default_rng(1)
    a = CAM.unproject(rng.uniform([0, 0], [800, 600], (200, 2)))
    depth = rng.uniform(5, 50, 200)
    X = a * depth[:, None]
    b = X - HEADING * 0.3
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    h, r = fit_heading(a[None], b, 1e-4)
    assert abs(float(h[0] @ HEADING)) == pytest.approx(1.0, abs=1e-6)
    assert float(np.max(r)) < 1e-9


def test_heading_search_decides_a_drive_that_the_rotation_search_does_not() -> None:
    gyro = _gyro(3)
    tracks = _drive(gyro, HEADING, seed=3, dashboard=25, vehicle=15)
    hs = _search(gyro, tracks)
    check_axes(hs.search)
    P = proper_axis_permutations()
    np.testing.assert_array_equal(hs.search.R_cam_imu, P[P_TRUE])
    assert abs(hs.search.winner.timeshift_s) <= 4e-4
    assert hs.search.winner.score_px < 0.15 and hs.search.margin > 3
    assert abs(float(hs.heading_cam @ HEADING)) > 0.999
    # the dashboard and the vehicle are left out; the dashboard is seen to stay still
    # (of ~490 dashboard tracks scored, those the gyro turns by more than 1.5 px are "still")
    assert hs.n_still >= 100 and hs.n_left_out >= hs.n_still + 100
    assert hs.still_box_px is not None and hs.still_box_px[1] >= 449
    # negative control: the images' own rotations (a zoom about the principal point as the
    # only translation) leave parallax that no candidate explains, or decide wrongly
    pa, pb, pair, t = tracks
    rots = rotations_from_pairs(
        pa, pb, pair, t, np.full(t.size, EXPOSURE_S), CAM, pair_fit=fit_rotation_translating
    )
    rs = search_axes(rots, gyro.upsampled(GYRO_UPSAMPLE), 575.0, 0.0, 0.02, "rotation")
    assert rs.winner.score_px > 3 * hs.search.winner.score_px
    with pytest.raises(AxisSearchError):
        check_axes(rs)


def test_a_gyro_of_another_recording_is_refused() -> None:
    tracks = _drive(_gyro(3), HEADING, seed=3)
    hs = _search(_gyro(4), tracks)
    with pytest.raises(AxisSearchError):
        check_axes(hs.search)
