"""Axis discovery under forward translation (calib.axes.translation): synthetic tracks of a
textured plane approached by a shaking camera, with the simulator's gyro and known axes."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.rotation import so3_exp, so3_log
from calib.axes.rotations import fit_rotation, rotations_from_pairs
from calib.axes.search import check_axes, search_axes
from calib.axes.translation import fit_rotation_translating, fit_rotation_zoom, zoomed
from calib.errors import AxisSearchError
from rigs.sim.preset import NOMINAL_R_CAM_IMU, get_preset
from rigs.sim.rig import SimRig

DEPTH_M = 8.0
#: 0.2 m per frame at 30 fps towards a plane 8 m away: pure-rotation registration is refused
SPEED_MPS = 6.0
NOISE_PX = 0.2


def _tracks(seed: int, speed_mps: float, frames: int = 20, n: int = 300):
    """Points of a plane ``DEPTH_M`` ahead of the first frame's optical axis, seen in every
    pair of consecutive frames (each at its own row's exposure midpoint) by a camera that
    shakes as the simulator's rig does and travels along that axis at ``speed_mps``."""
    rig = SimRig(get_preset("realistic"), seed, frames)
    cam, exp = rig.camera, rig.preset.exposure_s
    t = (rig.frame_times_ns - rig.frame_times_ns[0]) * 1e-9
    t_abs0 = rig.frame_times_ns[0] * 1e-9
    rng = np.random.default_rng(seed)
    axis = rig.motion.orientation(np.array([t_abs0]))[0][:, 2]

    def centre(tt: np.ndarray) -> np.ndarray:
        return speed_mps * (tt - t_abs0)[:, None] * axis

    def seen(X: np.ndarray, f: int) -> np.ndarray:
        y = np.full(len(X), cam.height / 2)
        for _ in range(3):  # the row's time depends on the row it lands on
            tt = t_abs0 + t[f] + cam.readout_s * y / cam.height + exp / 2
            R = rig.motion.orientation(tt)
            p = cam.project(np.einsum("nji,nj->ni", R, X - centre(tt)))
            y = p[:, 1]
        return p

    pa, pb, pair = [], [], []
    for f in range(frames - 1):
        px = rng.uniform([20, 20], [cam.width - 20, cam.height - 20], (n, 2))
        tt = t_abs0 + t[f] + cam.readout_s * px[:, 1] / cam.height + exp / 2
        d = np.einsum("nij,nj->ni", rig.motion.orientation(tt), cam.unproject(px))
        c = centre(tt)
        X = c + ((DEPTH_M - c @ axis) / (d @ axis))[:, None] * d
        a, b = seen(X, f), seen(X, f + 1)
        ok = np.all((b > 0) & (b < [cam.width, cam.height]), axis=1)
        pa.append(a[ok] + rng.normal(0, NOISE_PX, a[ok].shape))
        pb.append(b[ok] + rng.normal(0, NOISE_PX, b[ok].shape))
        pair.append(np.full(np.count_nonzero(ok), f))
    ti = rig.gyro_times_ns() * 1e-9 - t_abs0
    gyro = GyroTrace(ti, rig.sample_gyro(ti + t_abs0))
    args = (np.concatenate(pa), np.concatenate(pb), np.concatenate(pair), t, np.full(frames, exp))
    return rig, args, gyro


def _search(rig, args, gyro, translation: bool):
    fit = fit_rotation_translating if translation else None
    rots = rotations_from_pairs(*args, rig.camera, pair_fit=fit)
    return rots, search_axes(rots, gyro, rig.camera.intrinsics[0], 0.0, 0.06, "test")


def test_zoom_fit_recovers_rotation_and_zoom() -> None:
    rng = np.random.default_rng(2)
    x = rng.uniform(-0.6, 0.6, (200, 2))
    a = np.concatenate([x, np.ones((200, 1))], axis=1)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    R = so3_exp(np.array([0.004, -0.01, 0.006]))
    b = zoomed(a, 0.02) @ R.T
    R0, _ = fit_rotation(a, b, 2e-3)
    Rz, _, s, r = fit_rotation_zoom(a, b, 2e-3)
    assert abs(s - 0.02) <= 5e-4 and r < 2e-4
    assert np.linalg.norm(so3_log(Rz.T @ R)) < 5e-4 < np.linalg.norm(so3_log(R0.T @ R))
    Rt, _, moved = fit_rotation_translating(a, b, 2e-3)
    assert moved and np.allclose(Rt, Rz)
    Rp, _, still = fit_rotation_translating(a, a @ R.T, 2e-3)  # pure rotation stays so
    assert not still and np.linalg.norm(so3_log(Rp.T @ R)) < 1e-6


@pytest.mark.parametrize("seed", [0, 1])
def test_translation_aware_search_decides_driving_axes(seed: int) -> None:
    rig, args, gyro = _tracks(seed, SPEED_MPS)
    # negative control: pure-rotation registration leaves the parallax and is refused
    rots0, res0 = _search(rig, args, gyro, translation=False)
    assert not rots0.translating.any()
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        check_axes(res0)
    rots, res = _search(rig, args, gyro, translation=True)
    assert rots.translating.mean() > 0.8 and "with translation" in res.source
    check_axes(res)
    assert np.allclose(res.R_cam_imu, NOMINAL_R_CAM_IMU)
    assert abs(res.winner.timeshift_s - rig.calibration.timeshift_cam_imu_s) < 2e-3
    assert res.winner.score_px < 0.25 * res0.winner.score_px


def test_far_scene_keeps_pure_rotation() -> None:
    rig, args, gyro = _tracks(0, 0.0)
    _, res0 = _search(rig, args, gyro, translation=False)
    rots, res = _search(rig, args, gyro, translation=True)
    assert rots.translating.mean() < 0.2
    check_axes(res)
    assert np.allclose(res.R_cam_imu, NOMINAL_R_CAM_IMU)
    assert abs(res.winner.score_px - res0.winner.score_px) < 0.1 * res0.winner.score_px + 0.05


def test_wrong_gyro_is_refused_with_translation() -> None:
    rig, args, _ = _tracks(0, SPEED_MPS)
    _, _, other = _tracks(7, SPEED_MPS)  # another recording's gyro, same clock
    _, res = _search(rig, args, other, translation=True)
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        check_axes(res)
