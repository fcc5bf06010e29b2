"""A small simulated laser-grid session with exact streak truth, for tests and examples.

Global shutter, identity camera–IMU rotation and zero time shift (so the session's initial
guesses are the truth); ω is a smooth random shake. Dot directions are fixed in the world;
each frame's streaks are the dots' image tracks over the exposure (the core blur model's
``point_track``), rendered by :func:`blurtrack.testing.streak_frames.render_streaks`. The
project's full simulator lives in ``rigs``; this one is deliberately minimal.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter
from blurtrack.testing.streak_frames import quantise, render_streaks


def shake(t_s: np.ndarray, seed: int, amplitude_radps: float) -> np.ndarray:
    """Smooth random angular velocity ``(N, 3)`` rad/s: a few sinusoids per axis (1-6 Hz)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((t_s.size, 3))
    for axis in range(3):
        for _ in range(3):
            f = rng.uniform(1.0, 6.0)
            out[:, axis] += rng.normal(0, amplitude_radps / 2) * np.sin(
                2 * np.pi * f * t_s + rng.uniform(0, 2 * np.pi)
            )
    return out


def write_synthetic_session(
    folder: str | Path,
    n_frames: int = 4,
    seed: int = 0,
    resolution: tuple[int, int] = (320, 240),
    grid: tuple[int, int] = (5, 4),
    amplitude_radps: float = 4.0,
    fps: float = 30.0,
    exposure_s: float = 0.012,
    sigma_px: float = 1.5,
    noise: float = 0.004,
    with_imu: bool = True,
    timeshift_s: float = 0.0,
) -> dict[str, Any]:
    """Write a session folder and return its truth (``truth.yaml`` ``frames`` layout).

    ``timeshift_s``: true camera-IMU time shift (``t_imu = t_cam + shift``) of the written
    gyro samples; session.yaml still guesses 0, like a rig that does not know its offset.
    """
    W, H = resolution
    f = 0.9 * W
    camera = Camera(resolution=(W, H), intrinsics=(f, f, (W - 1) / 2, (H - 1) / 2))
    meta = SessionMeta(camera=camera, imu=ImuConfig(rate_hz=1000.0))
    t_imu = np.arange(0.0, (n_frames + 2) / fps, 1e-3)
    omega = shake(t_imu, seed, amplitude_radps)
    model = BlurModel(
        Calibration(camera=camera, R_cam_imu=np.eye(3), timeshift_cam_imu_s=0.0),
        GyroTrace(t_imu, omega),
    )
    gx, gy = grid
    xs = (np.arange(gx) + 0.5) * W / gx
    ys = (np.arange(gy) + 0.5) * H / gy
    dots = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    t_ref = 0.5 / fps
    rng = np.random.default_rng(seed + 1)
    frames: list[dict[str, Any]] = []
    with SessionWriter(folder, meta) as w:
        if with_imu:
            w.add_imu(np.rint((t_imu + timeshift_s) * 1e9).astype(np.int64), omega)
        for k in range(n_frames):
            t0 = (k + 1) / fps
            times = np.linspace(t0, t0 + exposure_s, 600)
            tracks = (
                model.point_track(
                    dots, np.full(len(dots), t_ref), np.broadcast_to(times, (len(dots), times.size))
                )
                if len(dots)
                else np.zeros((0, times.size, 2))
            )
            flux = rng.uniform(1.5, 3.0, len(dots))
            img = render_streaks((H, W), list(tracks), flux, sigma_px, 0.03, noise, seed + k)
            ts = round(t0 * 1e9)
            w.add_frame(ts, quantise(img), round(exposure_s * 1e9))
            streaks = []
            for d, tr in enumerate(tracks):
                inside = bool(np.all((tr >= 0) & (tr <= [W - 1, H - 1])))
                streaks.append(
                    {
                        "dot": d,
                        "start": tr[0].tolist(),
                        "end": tr[-1].tolist(),
                        "centerline": [*tr[::20].tolist(), tr[-1].tolist()],
                        "inside": inside,
                    }
                )
            frames.append({"index": k, "timestamp_ns": ts, "streaks": streaks})
        truth = {"frames": frames}
        w.write_truth(truth)
    return truth
