"""Synthetic calibration problems from the core blur model (known truth, no images).

A smooth hand-shake motion (sampled densely for the truth, at the gyro rate for the
measurement), random laser-dot directions per frame, true streak endpoints from
:meth:`blurtrack.geometry.blur_model.BlurModel.streak_endpoints`, then endpoint and gyro noise.
Used by
tests and benchmarks to check the solver independently of the simulator and detector.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.rotation import so3_exp
from calib.data import StreakSet, centre_points

#: Sampling rate of the "continuous" true motion behind the truth endpoints.
TRUTH_RATE_HZ = 4000.0


@dataclass(frozen=True)
class SyntheticProblem:
    streaks: StreakSet
    gyro: GyroTrace  # measured (bias and noise included), absolute IMU clock
    truth: Calibration
    initial: Calibration


def shake_function(
    rng: np.random.Generator, amp_radps: float = 1.0, roll: float = 1.0
) -> Callable[[np.ndarray], np.ndarray]:
    """Smooth angular velocity ``t (N,) -> (N, 3)``: sums of random 1–8 Hz sinusoids per axis."""
    freq = rng.uniform(1.0, 8.0, (3, 5))
    amp = rng.normal(0, amp_radps / 2, (3, 5)) * np.array([[1.0], [1.0], [roll]])
    phase = rng.uniform(0, 2 * np.pi, (3, 5))

    def omega(t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, float)[:, None, None]
        return np.sum(amp * np.sin(2 * np.pi * freq * t + phase), axis=2)

    return omega


def make_problem(
    seed: int = 0,
    n_frames: int = 40,
    dots_per_frame: int = 60,
    endpoint_noise_px: float = 0.1,
    gyro_noise_radps: float = 0.0,
    roll: float = 1.0,
    amp_radps: float = 1.0,
    rate_hz: float = 200.0,
    shift_error_s: float = 0.03,
    focal_error: float = 0.05,
    gyro_scale: np.ndarray | None = None,
    centre_k: int = 0,
    centre_noise_px: float = 0.0,
    readout_s: float = 0.025,
    tracked: bool = False,
    end_bias_px: float = 0.0,
) -> SyntheticProblem:
    """A known-truth problem; the initial guess is off by ``shift_error_s`` and ``focal_error``.

    ``gyro_scale``: the ``I + S`` (3, 3) of ``ω_meas = (I + S) ω_true + bias + noise``.
    ``centre_k > 0``: the streaks carry that many points of their true centre line (the true
    track sampled at 33 times over the streak, resampled by :func:`calib.data.centre_points`),
    with Gaussian noise ``centre_noise_px`` per coordinate. ``readout_s``: the true rolling-shutter
    readout (0: a global shutter, which the initial guess then states exactly; else the guess
    is 20 ms). ``tracked``: the dots are fixed in the scene (a laser grid), so each frame sees
    the dots of the previous one where they moved to (dots that leave the frame are replaced
    by new ones with new ids), and the streaks carry their time midpoints (with the endpoint
    noise): what :mod:`calib.tracks` pairs. ``end_bias_px``: both ends of every streak moved
    outwards along the streak by this much (a detector's length bias; midpoints unaffected).
    """
    rng = np.random.default_rng(seed)
    cam = Camera(
        resolution=(1280, 720), intrinsics=(1000.0, 1004.0, 645.0, 355.0), readout_s=readout_s
    )
    R0 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    R_true = so3_exp(np.array([0.01, -0.015, 0.02])) @ R0
    truth = Calibration(
        camera=cam,
        R_cam_imu=R_true,
        timeshift_cam_imu_s=0.0123,
        gyro_bias_radps=np.array([0.004, -0.006, 0.002]),
    )
    period, exposure = 0.05, 0.02
    frame_t = 100.0 + period * np.arange(n_frames)
    omega = shake_function(rng, amp_radps, roll)
    # Truth from the continuous motion (densely sampled); the gyro samples it at rate_hz.
    t_dense = np.arange(frame_t[0] - 0.3, frame_t[-1] + 0.3, 1.0 / TRUTH_RATE_HZ)
    model = BlurModel(truth, GyroTrace(t_dense, omega(t_dense) + truth.gyro_bias_radps))
    t_imu = np.arange(frame_t[0] - 0.25, frame_t[-1] + 0.25, 1.0 / rate_hz)
    w_true = omega(t_imu)
    starts, ends, fts, frames, ids, centres, mids = [], [], [], [], [], [], []

    def new_dots(n: int) -> np.ndarray:
        return np.stack([rng.uniform(40, 1240, n), rng.uniform(40, 680, n)], axis=1)

    dot_id = np.arange(dots_per_frame)
    px = np.zeros((0, 2))
    t_prev = 0.0
    for i, ft in enumerate(frame_t):
        t_ref = model.default_reference_time(ft, exposure)
        if not tracked or i == 0:
            px = new_dots(dots_per_frame)
        else:
            px = model.point_track(px, np.full(len(px), t_prev), np.array([t_ref]))[:, 0]
            gone = ~np.all((px > [40, 40]) & (px < [1240, 680]), axis=1)
            px[gone] = new_dots(int(gone.sum()))
            dot_id = dot_id.copy()
            dot_id[gone] = dot_id.max() + 1 + np.arange(int(gone.sum()))
        t_prev = t_ref
        s, e, ts, te = model.streak_endpoints(px, t_ref, ft, exposure)
        ok = np.all((s > 3) & (e > 3) & (s < [1276, 716]) & (e < [1276, 716]), axis=1)
        if tracked:
            mids.append(
                model.point_track(px[ok], np.full(ok.sum(), t_ref), ((ts + te) / 2)[ok, None])[:, 0]
            )
        if centre_k:
            tau = np.linspace(0.0, 1.0, 33)
            path = model.point_track(
                px[ok], np.full(ok.sum(), t_ref), ts[ok, None] + (te - ts)[ok, None] * tau
            )
            centres.append(
                np.array([centre_points(q, centre_k) for q in path]).reshape(-1, centre_k, 2)
            )
        starts.append(s[ok])
        ends.append(e[ok])
        fts.append(np.full(ok.sum(), ft))
        frames.append(np.full(ok.sum(), i))
        ids.append(dot_id[ok])
    start = np.concatenate(starts)
    end = np.concatenate(ends)
    if end_bias_px:
        d = (end - start) / np.maximum(np.linalg.norm(end - start, axis=1), 1e-9)[:, None]
        start, end = start - end_bias_px * d, end + end_bias_px * d
    start = start + rng.normal(0, endpoint_noise_px, start.shape)
    end = end + rng.normal(0, endpoint_noise_px, start.shape)
    mid = None
    if tracked:
        mid = np.concatenate(mids) + rng.normal(0, endpoint_noise_px, start.shape)
    ft_all = np.concatenate(fts)
    centre = None
    if centre_k:
        centre = np.concatenate(centres)
        centre = centre + rng.normal(0, centre_noise_px, centre.shape)
    streaks = StreakSet(
        start,
        end,
        ft_all - frame_t[0],
        np.full(ft_all.size, exposure),
        np.concatenate(frames),
        np.concatenate(ids),
        t0_s=float(frame_t[0]),
        centre=centre,
        mid=mid,
    )
    M = np.eye(3) if gyro_scale is None else np.asarray(gyro_scale, float)
    w_meas = w_true @ M.T + truth.gyro_bias_radps + rng.normal(0, gyro_noise_radps, w_true.shape)
    gyro = GyroTrace(t_imu, w_meas)
    fx, fy = cam.intrinsics[:2]
    initial = Calibration(
        camera=Camera(
            cam.resolution,
            (fx * (1 + focal_error), fy * (1 + focal_error), 639.5, 359.5),
            readout_s=0.02 if readout_s else 0.0,
        ),
        R_cam_imu=R0,
        timeshift_cam_imu_s=truth.timeshift_cam_imu_s + shift_error_s,
    )
    return SyntheticProblem(streaks, gyro, truth, initial)
