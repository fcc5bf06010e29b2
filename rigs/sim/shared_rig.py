"""Virtual devices driven by one simulated laser-grid rig (``rigs.sim``), selected by URL.

``sim://imu?rig=clean&seed=1&frames=60`` and ``sim://camera?rig=clean&seed=1&frames=60`` open
the same :class:`rigs.sim.rig.SimRig` (one per preset, seed and frame count in a process), on
one simulated timeline that starts at a shared host-clock origin half a second after the first
of the two is opened. Simulation time ``t`` is camera-clock time ``t_cam = first frame + t``;
the board samples the rig's gyro at IMU-clock time ``t_cam + timeshift`` and the camera renders
the frame starting at ``t_cam``. The board starts 0.1 s before the first frame and stops 0.2 s
after the last one (the rig's motion is defined only around its frames); the camera stops after
``frames`` frames.

A recorded session measures the physical timing of the recording (transport latency included),
not the rig's simulated time shift, so no truth.yaml is written for it; ``blurtrack simulate``
is the way to get sessions with truth.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from rigs.clock import Clock, MonotonicClock
from rigs.errors import DeviceUrlError

ORIGIN_DELAY_NS = 500_000_000
IMU_LEAD_S = 0.1  # the board starts this long before the first frame (gyro coverage)
IMU_TAIL_S = 0.2
_LOCK = threading.Lock()
_SHARED: dict[tuple[str, int, int], SharedRig] = {}


@dataclass(frozen=True)
class SharedRig:
    """A rig, its first frame on the camera clock (s) and the host origin of simulation time."""

    rig: Any  # rigs.sim.rig.SimRig
    cam0_s: float
    origin_ns: int

    @property
    def fps(self) -> float:
        return float(self.rig.preset.fps)

    @property
    def exposure_s(self) -> float:
        return float(self.rig.preset.exposure_s)

    @property
    def imu_rate_hz(self) -> float:
        return float(self.rig.preset.imu_rate_hz)

    @property
    def imu_origin_ns(self) -> int:
        """Host time of the board's sample 0 (IMU_LEAD_S before the first frame)."""
        return self.origin_ns - round(IMU_LEAD_S * 1e9)

    def imu_clock_s(self, t_board_s: np.ndarray) -> np.ndarray:
        """The rig's IMU-clock time of board times (s since the board's sample 0)."""
        shift = float(self.rig.gyro_model.timeshift_cam_imu_s)
        return self.cam0_s - IMU_LEAD_S + np.asarray(t_board_s, dtype=float) + shift

    def omega_at(self, t_board_s: np.ndarray) -> np.ndarray:
        """Gyro readings (M, 3) rad/s, IMU frame, at board times (M,) s."""
        return self.rig.sample_gyro(self.imu_clock_s(t_board_s))

    def render(self, t_start_s: float) -> np.ndarray:
        """The frame whose top row starts at simulation time ``t_start_s``."""
        return self.rig.render_frame(self.cam0_s + t_start_s)

    def imu_samples(self) -> int:
        """Samples that keep the board inside the rig's motion span."""
        n_frames = int(self.rig.n_frames)
        span_s = IMU_LEAD_S + (n_frames - 1) / self.fps + self.exposure_s + IMU_TAIL_S
        return int(span_s * self.imu_rate_hz)


def shared_rig(preset: str, seed: int, frames: int, clock: Clock | None = None) -> SharedRig:
    """The process-wide rig for (preset, seed, frames), created on first use."""
    key = (preset, int(seed), int(frames))
    with _LOCK:
        if key not in _SHARED:
            try:
                from rigs.sim.preset import get_preset
                from rigs.sim.rig import SimRig
            except ModuleNotFoundError:
                raise DeviceUrlError(
                    "rig=... needs the rigs.sim simulator, which is not installed"
                ) from None
            rig = SimRig(get_preset(preset), int(seed), int(frames))
            cam0_s = float(rig.frame_times_ns[0]) * 1e-9
            origin = (clock or MonotonicClock()).now_ns() + ORIGIN_DELAY_NS
            _SHARED[key] = SharedRig(rig, cam0_s, origin)
        return _SHARED[key]


def rig_from_params(url: str, params: dict[str, str], clock: Clock | None) -> SharedRig:
    """Read ``rig``, ``seed`` and ``frames`` from URL options (all required together)."""
    try:
        seed = int(params.get("seed", "0"))
        frames = int(params["frames"])
    except KeyError:
        raise DeviceUrlError(f"{url}: rig=... needs frames=N (the same on both devices)") from None
    except ValueError:
        raise DeviceUrlError(f"{url}: seed and frames must be integers") from None
    if not 1 <= frames <= 100_000 or seed < 0:
        raise DeviceUrlError(f"{url}: frames must be in [1, 100000] and seed >= 0")
    return shared_rig(params["rig"], seed, frames, clock)


def rig_guess_for_urls(*urls: str | None) -> dict[str, Any] | None:
    """What a ``rig=...`` device URL's rig says about itself (session.yaml's initial guesses:
    nominal intrinsics, readout and IMU mounting), or None when no URL names a rig."""
    from rigs.urls import parse_device_url

    for url in urls:
        if not url:
            continue
        u = parse_device_url(url)
        if u.scheme == "sim" and "rig" in u.params:
            meta = rig_from_params(url, u.params, None).rig.nominal_meta()
            return {
                "intrinsics": list(meta.camera.intrinsics),
                "readout_s": meta.camera.readout_s,
                "R_cam_imu": np.asarray(meta.imu.T_cam_imu)[:3, :3].tolist(),
            }
    return None
