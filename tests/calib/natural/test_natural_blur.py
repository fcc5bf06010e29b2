"""Equal-blur tracks (calib.natural.blur.equal_blur_tracks) against the simulator's truth: on a
strongly blurred simulated far scene the refined tracks carry each point's mid-exposure
position to the other frame's far more exactly than Lucas–Kanade's points with the blur
centroid removed (the negative control), and the kernels follow the true motion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blurtrack.features.tracks import track_frames
from blurtrack.io.session import load_session
from calib.natural.blur import corrected_tracks, equal_blur_tracks, exposure_offsets
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

#: A small image with 720p's blur in pixels (fx 1000 at 320x180: streaks of 5-15 px).
TELE = dict(width=320, height=180, focal_px=1000.0)


@pytest.fixture(scope="module")
def blurred(tmp_path_factory, shared_data) -> tuple[NaturalRig, Path]:
    rig = NaturalRig(get_preset("realistic").replace(**TELE), 0, 10)
    out = tmp_path_factory.mktemp("natblur") / "s"
    write_session(rig, out)
    return rig, out


def _true_warp(rig: NaturalRig, p: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = rig.camera.intrinsics
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    x = np.column_stack([p, np.ones(len(p))]) @ np.linalg.inv(K).T
    w = np.einsum("nij,nj->ni", rig.motion.orientation(t0), x)
    q = np.einsum("nji,nj->ni", rig.motion.orientation(t1), w) @ K.T
    return q[:, :2] / q[:, 2:3]


def _mid_time(rig: NaturalRig, frame: np.ndarray, y: np.ndarray) -> np.ndarray:
    H = rig.camera.height
    t = rig.frame_times_ns[frame] * 1e-9
    return t + rig.camera.readout_s * y / H + rig.preset.exposure_s / 2


def _errors(rig: NaturalRig, tracks) -> np.ndarray:
    """Tracked end minus where the true motion carries the first end's mid-exposure
    position (both dated at their own rows' mid-exposure)."""
    a, b = tracks.frame_a, tracks.frame_b
    pa, pb = tracks.pts_a, tracks.pts_b
    return pb - _true_warp(rig, pa, _mid_time(rig, a, pa[:, 1]), _mid_time(rig, b, pb[:, 1]))


def test_kernels_follow_the_true_motion(blurred) -> None:
    rig, path = blurred
    s = load_session(path)
    ts = s.frames["timestamp_ns"].to_numpy(np.int64)
    rng = np.random.default_rng(0)
    p = rng.uniform([20, 20], [300, 160], (50, 2))
    f = rng.integers(0, 10, 50)
    t = ts[f] * 1e-9
    e = np.full(50, rig.preset.exposure_s)
    o = exposure_offsets(p, t, e, rig.calibration, s.gyro())
    n = o.shape[1]
    tm = _mid_time(rig, f, p[:, 1])
    frac = (np.arange(n) + 0.5) / n - 0.5
    true = np.stack([_true_warp(rig, p, tm, tm + e * k) - p for k in frac], axis=1)
    length = np.linalg.norm(true[:, -1] - true[:, 0], axis=1)
    assert np.median(length) > 4  # the blur this test is about
    # the gyro's noise and unmodelled scale error: a few hundredths of a pixel
    assert np.max(np.abs(o - true)) < 0.1
    assert n >= 2 * np.max(length)  # samples at most 0.5 px apart


def test_equal_blur_tracks_are_unbiased_where_centroids_are_not(blurred) -> None:
    rig, path = blurred
    s = load_session(path)
    ts = s.frames["timestamp_ns"].to_numpy(np.int64)
    ex = s.frames["exposure_ns"].to_numpy(np.int64)
    tracks = track_frames(s.read_image, len(ts))
    gyro = s.gyro()
    cen = _errors(rig, corrected_tracks(tracks, ts, ex, rig.calibration, gyro))
    eq_tracks = equal_blur_tracks(tracks, s.read_image, ts, ex, rig.calibration, gyro)
    eq = _errors(rig, eq_tracks)
    assert len(eq_tracks) > 0.95 * len(tracks) > 500
    med_c, med_e = (np.median(np.linalg.norm(x, axis=1)) for x in (cen, eq))
    rms_c, rms_e = (np.sqrt(np.mean(x**2)) for x in (cen, eq))
    # measured: centroid-corrected LK 0.59 px median / 0.84 px RMS, equal blur
    # 0.20 / 0.27
    assert med_e < 0.3 and rms_e < 0.4
    assert med_c > 1.8 * med_e and rms_c > 2 * rms_e  # negative control
