"""The simulated laser-grid rig: true calibration, true motion, renderer and gyro in one object.

:class:`SimRig` draws every true value from its preset and seed (deterministically) and offers
the small API that virtual devices and tests plug into:

- ``omega_cam_at(t_cam_s) -> (M, 3)``: the true camera angular velocity (rad/s);
- ``sample_gyro(t_imu_s) -> (M, 3)``: what the gyro reports at IMU-clock times;
- ``render_frame(t_start_s) -> image``: the frame whose top row starts exposing at ``t_start_s``;
- ``render_sharp(t_ref_s) -> image``: the same scene without motion, at a reference time;
- ``streaks(t_start_s)``: the true streaks of a frame; ``frame_truth(i)``: their truth.yaml entry.

Random streams (``np.random.SeedSequence([seed, stream, ...])``): 0 true parameters, 1 motion,
2 gyro noise, 3 image noise (per frame, keyed by its timestamp in ns, so any frame renders the
same whatever the order), 4 dot jitter.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.rotation import so3_exp
from blurtrack.io.session import ImuConfig, SessionMeta
from rigs.sim.dots import TrueFrameStreaks, dot_directions, dot_pixels, frame_streaks
from rigs.sim.errors import SimError
from rigs.sim.imu import GyroModel
from rigs.sim.motion import TrueMotion, shake_omega, synthetic_omega
from rigs.sim.preset import NOMINAL_R_CAM_IMU, SimPreset
from rigs.sim.render import ambient_map, expose, render_points, render_streaks
from rigs.sim.shake import ShakeTrace, default_shake_path, read_shake_trace

#: Camera clock of the first frame (ns); far from 0 so stamps look like a real clock's.
FIRST_FRAME_NS = 1_000_000_000
#: True motion and gyro samples extend this far beyond the frames (s).
MOTION_MARGIN_S = 0.5
GYRO_MARGIN_S = 0.1
MAX_FRAMES = 100_000
#: Longest simulated recording (s): keeps the motion table under ~150 MB and its error tiny.
MAX_DURATION_S = 600.0


def _rng(seed: int, *stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), *map(int, stream)]))


class SimRig:
    """A simulated rig for ``n_frames`` frames of ``preset`` with random seed ``seed``.

    Args:
        shake: a loaded :class:`ShakeTrace` or a path to one for ``motion: shake`` presets
            (default: the project's GyroDeblurNet traces under ``../shared/data``).
    """

    def __init__(
        self,
        preset: SimPreset,
        seed: int,
        n_frames: int,
        shake: ShakeTrace | str | Path | None = None,
    ) -> None:
        if not 1 <= int(n_frames) <= MAX_FRAMES:
            raise SimError(f"frames must be in [1, {MAX_FRAMES}], got {n_frames}")
        if int(seed) < 0:
            raise SimError(f"seed must be >= 0, got {seed}")
        if int(n_frames) / preset.fps > MAX_DURATION_S:
            raise SimError(
                f"{n_frames} frames at {preset.fps:g} fps exceed the simulator's "
                f"{MAX_DURATION_S:g} s limit"
            )
        self.preset = p = preset
        self.seed = int(seed)
        self.n_frames = int(n_frames)
        rng = _rng(self.seed, 0)
        W, H = p.width, p.height

        # --- true camera (nominal perturbed within the preset's spreads)
        fx = p.focal_px * (1 + rng.uniform(-p.focal_spread, p.focal_spread))
        fy = fx * (1 + rng.uniform(-p.aspect_spread, p.aspect_spread))
        dc = rng.uniform(-1, 1, 2) * p.principal_spread_px
        cx, cy = (W - 1) / 2 + dc[0], (H - 1) / 2 + dc[1]
        readout = p.readout_s * (1 + rng.uniform(-p.readout_spread, p.readout_spread))
        self.camera = Camera(
            (W, H),
            (fx, fy, cx, cy),
            "radtan" if p.distortion_coeffs else "none",
            p.distortion_coeffs,
            readout,
        )
        # --- true gyro mounting, bias, scale, offset
        R_nom = np.array(NOMINAL_R_CAM_IMU)
        axis = rng.standard_normal(3)
        angle = math.radians(rng.uniform(*p.misalignment_deg))
        R_true = so3_exp(axis / np.linalg.norm(axis) * angle) @ R_nom
        shift = rng.uniform(*p.timeshift_s) * (1.0 if rng.uniform() < 0.5 else -1.0)
        bias = rng.uniform(-p.gyro_bias_radps, p.gyro_bias_radps, 3)
        scale = np.eye(3) + rng.normal(0.0, p.gyro_scale_error, (3, 3))
        self.gyro_model = GyroModel(R_true, shift, bias, scale, p.gyro_noise_radps)
        self.calibration = Calibration(
            self.camera, R_cam_imu=R_true, timeshift_cam_imu_s=shift, gyro_bias_radps=bias
        )
        self.misalignment_deg = math.degrees(angle)

        # --- frames (camera clock)
        period_ns = 1e9 / p.fps
        self.frame_times_ns = FIRST_FRAME_NS + np.round(
            np.arange(self.n_frames) * period_ns
        ).astype(np.int64)
        self.exposure_ns = round(p.exposure_s * 1e9)
        # --- true motion over the frames plus margins (and the gyro's shifted span)
        t_lo = FIRST_FRAME_NS * 1e-9 - MOTION_MARGIN_S - abs(shift)
        t_hi = (
            float(self.frame_times_ns[-1]) * 1e-9
            + p.exposure_s
            + readout
            + MOTION_MARGIN_S
            + abs(shift)
        )
        mrng = _rng(self.seed, 1)
        if p.motion == "synthetic":
            t, w = synthetic_omega(mrng, t_hi - t_lo, p.synthetic_rms_radps, p.motion_band_hz)
            self.motion_info: dict[str, Any] = {"source": "synthetic"}
        else:
            trace = (
                shake
                if isinstance(shake, ShakeTrace)
                else read_shake_trace(default_shake_path() if shake is None else shake)
            )
            t, w, self.motion_info = shake_omega(
                trace, mrng, t_hi - t_lo, p.motion_scale, p.motion_band_hz
            )
        self.motion = TrueMotion(t + t_lo, w)
        self.dots_world = dot_directions(
            p.dot_cols, p.dot_rows, p.dot_fill, W, H, p.focal_px, p.dot_jitter, _rng(self.seed, 4)
        )
        self._gyro_rng = _rng(self.seed, 2)
        self._cache: tuple[float, TrueFrameStreaks] | None = None
        self._ambient = ambient_map(W, H, p.ambient_eps * p.exposure_s, p.vignetting)

    # ------------------------------------------------------------- guesses
    def nominal_meta(self) -> SessionMeta:
        """What the rig says about itself (session.yaml): datasheet values, not the truth."""
        p = self.preset
        guess = p.readout_s if p.readout_guess_s is None else p.readout_guess_s
        cam = Camera(
            (p.width, p.height),
            (p.focal_px, p.focal_px, (p.width - 1) / 2, (p.height - 1) / 2),
            readout_s=guess,
        )
        T = np.eye(4)
        T[:3, :3] = np.array(NOMINAL_R_CAM_IMU)
        return SessionMeta(
            cam,
            ImuConfig(p.imu_rate_hz, T, 0.0),
            "laser-grid",
            extra={"rig": {"kind": "simulated", "preset": p.name, "seed": self.seed}},
        )

    # ----------------------------------------------------------- pluggable
    def omega_cam_at(self, t_cam_s: np.ndarray) -> np.ndarray:
        """True camera-frame angular velocity ``(M, 3)`` (rad/s) at camera times ``(M,)``."""
        return self.motion.omega_cam_at(t_cam_s)

    def sample_gyro(self, t_imu_s: np.ndarray, noise: bool = True) -> np.ndarray:
        """Gyro readings ``(M, 3)`` (rad/s, IMU frame) at IMU-clock times ``(M,)``.

        Noise comes from the rig's gyro stream: the same sequence of calls gives the same
        samples.
        """
        if noise:
            return self.gyro_model.measure(self.omega_cam_at, t_imu_s, self._gyro_rng)
        return self.gyro_model.ideal(self.omega_cam_at, t_imu_s)

    def gyro_times_ns(self) -> np.ndarray:
        """The IMU's sample times (IMU clock, ns) covering every frame with a margin."""
        shift = self.gyro_model.timeshift_cam_imu_s
        lo = self.frame_times_ns[0] * 1e-9 + shift - GYRO_MARGIN_S
        hi = (
            self.frame_times_ns[-1] * 1e-9
            + self.preset.exposure_s
            + self.camera.readout_s
            + shift
            + GYRO_MARGIN_S
        )
        n = math.ceil((hi - lo) * self.preset.imu_rate_hz) + 1
        return round(lo * 1e9) + np.round(np.arange(n) * (1e9 / self.preset.imu_rate_hz)).astype(
            np.int64
        )

    def reference_time(self, t_start_s: float) -> float:
        """Mid-exposure of the centre row (BlurModel's default reference time)."""
        H = self.camera.height
        return t_start_s + self.camera.readout_s * (H - 1) / 2 / H + self.preset.exposure_s / 2

    def streaks(self, t_start_s: float) -> TrueFrameStreaks:
        """True streaks of the frame starting at ``t_start_s`` (cached for the last frame)."""
        cached = self._cache  # one read: virtual devices may call from several threads
        if cached is not None and cached[0] == t_start_s:
            return cached[1]
        s = frame_streaks(
            self.motion,
            self.camera,
            self.dots_world,
            t_start_s,
            self.preset.exposure_s,
            self.reference_time(t_start_s),
        )
        self._cache = (t_start_s, s)
        return s

    def render_electrons(self, t_start_s: float) -> np.ndarray:
        """Mean photo-electrons ``(H, W)`` of the dots (no ambient, no noise)."""
        p = self.preset
        return render_streaks(
            self.motion,
            self.camera,
            self.dots_world,
            self.streaks(t_start_s),
            t_start_s,
            p.exposure_s,
            p.dot_flux_eps,
            p.dot_sigma_px,
            p.substep_px,
        )

    def render_frame(self, t_start_s: float, noise: bool = True) -> np.ndarray:
        """The frame (uint8 or uint16, ``(H, W)``) whose top row starts at ``t_start_s``."""
        return self._expose(self.render_electrons(t_start_s), t_start_s, noise)

    def sharp_electrons(self, t_ref_s: float) -> np.ndarray:
        """Mean photo-electrons ``(H, W)`` of the dots without motion, as seen at ``t_ref_s``
        (each dot's whole exposure at one spot)."""
        p = self.preset
        J = self.dots_world.shape[0]
        px = dot_pixels(
            self.motion, self.camera, self.dots_world, np.full(J, t_ref_s), np.arange(J)
        )
        return render_points((p.height, p.width), px, p.dot_flux_eps * p.exposure_s, p.dot_sigma_px)

    def render_sharp(self, t_ref_s: float, noise: bool = False) -> np.ndarray:
        """The sharp frame (uint8/uint16): the scene without motion blur at ``t_ref_s``."""
        return self._expose(self.sharp_electrons(t_ref_s), t_ref_s, noise)

    def _expose(self, signal: np.ndarray, t_s: float, noise: bool) -> np.ndarray:
        p = self.preset
        rng = _rng(self.seed, 3, round(t_s * 1e9)) if noise else None
        return expose(
            signal,
            self._ambient,
            p.full_well_e,
            p.read_noise_e,
            p.shot_noise,
            p.bit_depth,
            rng,
            p.optics(),
        )

    # --------------------------------------------------------------- truth
    def frame_truth(self, index: int) -> dict[str, Any]:
        """truth.yaml entry of frame ``index``: every streak at least partly in the image."""
        ts_ns = int(self.frame_times_ns[index])
        s = self.streaks(ts_ns * 1e-9)
        out = []
        for j in np.flatnonzero(s.visible):
            out.append(
                {
                    "dot": int(j),
                    "start": _r(s.start[j], 6),
                    "end": _r(s.end[j], 6),
                    "mid": _r(s.mid[j], 6),
                    "t_start_ns": round(s.t_start_s[j] * 1e9),
                    "t_end_ns": round(s.t_end_s[j] * 1e9),
                    "centerline": [_r(q, 3) for q in s.centerline(int(j))],
                    "inside": bool(s.inside[j]),
                    "ref": _r(s.ref[j], 6),
                    "length_px": round(float(s.length_px[j]), 4),
                }
            )
        return {
            "index": int(index),
            "timestamp_ns": ts_ns,
            "exposure_ns": self.exposure_ns,
            "t_ref_ns": round(s.t_ref_s * 1e9),
            "streaks": out,
        }

    def simulator_info(self) -> dict[str, Any]:
        """Everything else the simulator knows (the ``simulator:`` block of truth.yaml)."""
        g = self.gyro_model
        return {
            "preset": self.preset.to_dict(),
            "seed": self.seed,
            "frames": self.n_frames,
            "motion": self.motion_info,
            "gyro": {
                "noise_radps": g.noise_radps,
                "scale_matrix": g.scale.tolist(),
                "misalignment_deg": self.misalignment_deg,
                "R_cam_imu_nominal": [list(r) for r in NOMINAL_R_CAM_IMU],
            },
            "dots": {
                "cols": self.preset.dot_cols,
                "rows": self.preset.dot_rows,
                "world_directions": np.round(self.dots_world, 12).tolist(),
            },
            "reference_time": "mid-exposure of the centre row (t_ref_ns); ref = dot there",
        }


def _r(xy: np.ndarray, nd: int) -> list[float]:
    return [round(float(xy[0]), nd), round(float(xy[1]), nd)]
