"""A virtual camera: frames from any renderer ``render(t_start_s) -> image`` on a fixed schedule.

Timestamps are the schedule's (what a camera driver with hardware stamps reports): frame i starts
exposing at ``t0 + i / fps`` on the host clock. In real time, a reader that falls more than
``buffer_frames`` behind loses the oldest frames, as a V4L2 ring buffer does, and they are
counted. ``dot_grid_renderer`` is a cheap stand-in scene until the laser-grid simulator
(rigs/sim) is plugged in through ``render``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rigs.camera_types import CameraFrame
from rigs.clock import Clock, MonotonicClock
from rigs.errors import RigConfigError

RenderFn = Callable[[float], np.ndarray]


def dot_grid_renderer(
    width: int,
    height: int,
    spacing_px: int = 40,
    amplitude_px: float = 6.0,
    freq_hz: float = 1.1,
    noise: float = 0.0,
    seed: int = 0,
) -> RenderFn:
    """A grid of bright dots on a dark background that sways sinusoidally (uint8, (H, W)).

    ``noise`` > 0 adds Gaussian sensor noise of that standard deviation (grey levels), drawn
    once into a few frames that are cycled, so that images compress like real ones without the
    renderer itself costing much CPU.
    """
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    dx = (xx % spacing_px) - spacing_px / 2
    dy = (yy % spacing_px) - spacing_px / 2
    base = (20 + 220 * np.exp(-(dx * dx + dy * dy) / 8.0)).astype(np.uint8)
    rng = np.random.default_rng(seed)
    noise_frames = (
        [np.clip(rng.normal(noise, noise, base.shape), 0, 255).astype(np.uint8) for _ in range(4)]
        if noise > 0
        else []
    )
    count = [0]

    def render(t_start_s: float) -> np.ndarray:
        sx = round(amplitude_px * np.sin(2 * np.pi * freq_hz * t_start_s))
        sy = round(amplitude_px * np.cos(2 * np.pi * 0.7 * freq_hz * t_start_s))
        image = np.roll(base, (sy, sx), axis=(0, 1))
        if noise_frames:
            count[0] += 1
            image = (
                np.add(image, noise_frames[count[0] % len(noise_frames)], dtype=np.uint16)
                .clip(0, 255)
                .astype(np.uint8)
            )
        return image

    return render


@dataclass(frozen=True)
class VirtualCameraConfig:
    """Frame rate, exposure, optional frame limit, pacing and host-side buffer depth. Frame i
    starts exposing at simulation time ``i / fps`` after ``origin_ns`` (default: creation), and
    ``render`` receives that simulation time; give a VirtualImu the same origin and both devices
    share one simulated timeline (e.g. ``render=lambda t: rig.render_frame(t0 + t)`` and
    ``omega_at=lambda t: rig.sample_gyro(t0 + t)`` for a rigs.sim rig)."""

    fps: float = 30.0
    exposure_s: float = 0.01
    n_frames: int | None = None
    realtime: bool = True
    buffer_frames: int = 4
    origin_ns: int | None = None  # host time of frame 0 (share it with a VirtualImu)

    def __post_init__(self) -> None:
        if not 0.1 <= self.fps <= 1000:
            raise RigConfigError(f"fps={self.fps} outside [0.1, 1000]")
        if not 0 < self.exposure_s <= 1.0 / self.fps:
            raise RigConfigError(f"exposure_s={self.exposure_s} must be in (0, 1/fps]")
        if self.buffer_frames < 1 or (self.n_frames is not None and self.n_frames < 0):
            raise RigConfigError("buffer_frames must be >= 1 and n_frames >= 0")


class VirtualCamera:
    """``read()`` returns the next frame, or None after ``n_frames``."""

    def __init__(
        self,
        render: RenderFn,
        config: VirtualCameraConfig | None = None,
        clock: Clock | None = None,
        url: str = "sim://camera",
    ) -> None:
        self.render = render
        self.config = config or VirtualCameraConfig()
        self.clock = clock or MonotonicClock()
        self.url = url
        self._t0_ns = (
            self.clock.now_ns() if self.config.origin_ns is None else self.config.origin_ns
        )
        self._next = 0
        self.frames_dropped = 0
        self._stop = threading.Event()

    def _due_ns(self, i: int) -> int:
        return self._t0_ns + round(i * 1e9 / self.config.fps)

    def read(self) -> CameraFrame | None:
        cfg = self.config
        if cfg.n_frames is not None and self._next >= cfg.n_frames:
            return None
        if cfg.realtime:
            # the frame is delivered when its exposure has ended
            exposure_ns = round(cfg.exposure_s * 1e9)
            while True:
                wait_ns = self._due_ns(self._next) + exposure_ns - self.clock.now_ns()
                if wait_ns <= 0 or self._stop.is_set():
                    break
                self._stop.wait(min(wait_ns * 1e-9, 0.05))
            # newest frame whose exposure has ended; the buffer keeps the last buffer_frames
            latest = int((self.clock.now_ns() - self._t0_ns - exposure_ns) * cfg.fps // 1e9)
            oldest_kept = latest - cfg.buffer_frames + 1
            if self._next < oldest_kept:
                skip = oldest_kept - self._next
                if cfg.n_frames is not None:
                    skip = min(skip, cfg.n_frames - self._next)
                self.frames_dropped += skip
                self._next += skip
                if cfg.n_frames is not None and self._next >= cfg.n_frames:
                    return None
        i = self._next
        self._next += 1
        t_ns = self._due_ns(i)
        image = np.asarray(self.render((t_ns - self._t0_ns) * 1e-9))
        return CameraFrame(
            i, image, t_ns, round(cfg.exposure_s * 1e9), self.clock.now_ns(), "driver"
        )

    def close(self) -> None:
        self._stop.set()
