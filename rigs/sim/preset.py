"""Simulator presets: frozen, self-validating parameter sets read and written as YAML.

A preset holds the rig's NOMINAL values (what a datasheet says; they go into ``session.yaml``)
and the spreads from which the seed draws the TRUE values (they go into ``truth.yaml``). Units
are in the field names: seconds, pixels, radians per second, photo-electrons (``e``).

>>> p = get_preset("realistic")
>>> p.exposure_s, p.imu_rate_hz
(0.02, 200.0)
>>> SimPreset.from_dict(p.to_dict()) == p
True
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from blurtrack.errors import ConfigError
from blurtrack.io.yamlio import read_yaml, write_yaml
from rigs.sim.errors import SimError
from rigs.sim.optics import Optics

MOTION_SOURCES = ("synthetic", "shake")

#: Nominal camera-IMU axis permutation (a proper rotation: x and y swapped, z flipped), as a
#: phone-style IMU mounted on a camera board might be; ``ω_cam = R_cam_imu ω_imu``.
NOMINAL_R_CAM_IMU: tuple[tuple[float, ...], ...] = (
    (0.0, 1.0, 0.0),
    (1.0, 0.0, 0.0),
    (0.0, 0.0, -1.0),
)


@dataclass(frozen=True)
class SimPreset:
    """All parameters of one simulated laser-grid recording (see docs/simulator.md)."""

    name: str = "custom"
    # --- camera (nominal values; truth = nominal perturbed by the seed within the spreads)
    width: int = 1280
    height: int = 720
    focal_px: float = 1000.0
    focal_spread: float = 0.0  # relative: true fx = focal (1 + U(-s, s))
    aspect_spread: float = 0.0  # relative: true fy = fx (1 + U(-s, s))
    principal_spread_px: float = 0.0  # true (cx, cy) = centre + U(-s, s) px
    distortion_coeffs: tuple[float, ...] = ()  # true radtan k1 k2 p1 p2; () = none
    fps: float = 30.0
    exposure_s: float = 0.01
    readout_s: float = 0.0  # nominal (datasheet) rolling-shutter readout
    readout_spread: float = 0.0  # relative: true readout = readout (1 + U(-s, s))
    readout_guess_s: float | None = None  # what session.yaml says; None = the nominal value
    # --- IMU
    imu_rate_hz: float = 1000.0
    gyro_noise_radps: float = 0.0  # white noise, 1-sigma per sample per axis
    gyro_bias_radps: float = 0.0  # true bias drawn U(-b, b) per axis (IMU frame)
    gyro_scale_error: float = 0.0  # true scale/cross-axis matrix I + N(0, s) entries
    misalignment_deg: tuple[float, float] = (0.0, 0.0)  # true extra rotation angle range
    timeshift_s: tuple[float, float] = (0.0, 0.0)  # |t_imu - t_cam| range; sign by seed
    # --- motion
    motion: str = "synthetic"  # "synthetic" or "shake" (GyroDeblurNet traces)
    motion_scale: tuple[float, float] = (1.0, 1.0)  # shake traces: scale range
    synthetic_rms_radps: tuple[float, float, float] = (0.6, 0.6, 0.3)
    motion_band_hz: tuple[float, float] = (1.0, 8.0)  # band-pass of the true ω
    # --- dot grid (a diffractive projector: a regular angular grid fixed in the world)
    dot_cols: int = 15
    dot_rows: int = 11
    dot_fill: float = 0.9  # the grid spans this fraction of the nominal view
    dot_jitter: float = 0.0  # random angular offset per dot, fraction of the spacing
    dot_sigma_px: float = 1.3  # Gaussian spread of a dot (px)
    dot_flux_eps: float = 2.0e7  # photo-electrons per second from one dot
    # --- radiometry
    ambient_eps: float = 2.0e4  # ambient light, photo-electrons per second per pixel
    vignetting: float = 0.0  # ambient falls by this fraction from centre to corner
    full_well_e: float = 10000.0
    read_noise_e: float = 0.0
    shot_noise: bool = False
    bit_depth: int = 8
    # --- rendering
    substep_px: float = 0.25  # largest dot displacement between render sub-steps
    # --- real optics (rigs/sim/optics.py; all off by default)
    speckle_contrast: float = 0.0  # laser speckle: std of the dots' mean-1 intensity field
    speckle_px: float = 1.5  # speckle grain (px, sigma of its correlation)
    lens_blur_px: float = 0.0  # extra blur sigma at the corners (grows as r^2 from the centre)
    chromatic_px: float = 0.0  # lateral chromatic aberration at the corner (px, colour only)
    colour_response: tuple[float, ...] = ()  # (r, g, b) response to the dots: Bayer sensor
    blooming: float = 0.0  # fraction of the charge above the full well spilled along columns
    jpeg_quality: int = 0  # 0 = lossless; else JPEG quality of the stored frames (8-bit)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, list):
                object.__setattr__(self, f.name, tuple(v))
        for f in fields(self):
            v = getattr(self, f.name)
            vals = v if isinstance(v, tuple) else (v,)
            _check(
                all(not isinstance(x, float) or math.isfinite(x) for x in vals),
                f"{f.name} must be finite",
            )
        _check(isinstance(self.name, str) and self.name != "", "name must be a non-empty string")
        _check(self.width >= 16 and self.height >= 16, "width and height must be >= 16 px")
        _check(self.width * self.height <= 50_000_000, "image larger than 50 Mpx")
        _check(self.focal_px > 0, "focal_px must be positive")
        for k in ("focal_spread", "aspect_spread", "readout_spread", "gyro_scale_error"):
            _check(0.0 <= getattr(self, k) < 0.5, f"{k} must be in [0, 0.5)")
        _check(
            0.0 <= self.principal_spread_px < min(self.width, self.height) / 4,
            "principal_spread_px out of range",
        )
        _check(len(self.distortion_coeffs) in (0, 4), "distortion_coeffs: 0 or 4 (k1 k2 p1 p2)")
        _check(self.fps > 0, "fps must be positive")
        _check(
            0.0 < self.exposure_s < 1.0 / self.fps,
            "exposure_s must be positive and shorter than the frame period",
        )
        _check(
            0.0 <= self.readout_s * (1 + self.readout_spread) < 1.0 / self.fps,
            "readout_s must be in [0, frame period)",
        )
        _check(
            self.readout_guess_s is None or 0.0 <= self.readout_guess_s < 1.0,
            "readout_guess_s must be in [0, 1) s",
        )
        _check(1.0 <= self.imu_rate_hz <= 10000.0, "imu_rate_hz must be in [1, 10000]")
        _check(
            self.gyro_noise_radps >= 0 and self.gyro_bias_radps >= 0,
            "gyro noise and bias must be >= 0",
        )
        _pair(self.misalignment_deg, "misalignment_deg", 0.0, 20.0)
        _pair(self.timeshift_s, "timeshift_s", 0.0, 1.0)
        _pair(self.motion_scale, "motion_scale", 0.0, 20.0)
        _pair(self.motion_band_hz, "motion_band_hz", 0.0, 200.0)
        _check(self.motion_band_hz[1] > 0, "motion_band_hz upper edge must be positive")
        _check(self.motion in MOTION_SOURCES, f"motion must be one of {MOTION_SOURCES}")
        _check(
            len(self.synthetic_rms_radps) == 3
            and all(0 <= v <= 50 for v in self.synthetic_rms_radps),
            "synthetic_rms_radps must be 3 values in [0, 50]",
        )
        _check(1 <= self.dot_cols <= 200 and 1 <= self.dot_rows <= 200, "dot grid 1..200")
        _check(0.0 < self.dot_fill <= 3.0, "dot_fill must be in (0, 3]")
        _check(0.0 <= self.dot_jitter <= 0.5, "dot_jitter must be in [0, 0.5]")
        _check(0.3 <= self.dot_sigma_px <= 5.0, "dot_sigma_px must be in [0.3, 5]")
        _check(self.dot_flux_eps >= 0 and self.ambient_eps >= 0, "fluxes must be >= 0")
        _check(0.0 <= self.vignetting < 1.0, "vignetting must be in [0, 1)")
        _check(self.full_well_e > 0 and self.read_noise_e >= 0, "full_well_e > 0, noise >= 0")
        _check(self.bit_depth in (8, 16), "bit_depth must be 8 or 16")
        _check(0.01 <= self.substep_px <= 2.0, "substep_px must be in [0.01, 2]")
        try:
            self.optics()
        except SimError as exc:
            raise SimError(f"preset: {exc}") from None
        _check(self.jpeg_quality == 0 or self.bit_depth == 8, "jpeg_quality needs bit_depth 8")

    def optics(self) -> Optics:
        """The real-optics effects of this preset (:class:`rigs.sim.optics.Optics`)."""
        return Optics(
            speckle_contrast=self.speckle_contrast,
            speckle_px=self.speckle_px,
            lens_blur_px=self.lens_blur_px,
            chromatic_px=self.chromatic_px,
            colour_response=self.colour_response,
            blooming=self.blooming,
            jpeg_quality=self.jpeg_quality,
        )

    # ----------------------------------------------------------------- YAML
    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str = "preset") -> SimPreset:
        """Build from a mapping; unknown keys and wrong types are errors, not ignored."""
        if not isinstance(data, dict):
            raise SimError(f"{source}: a preset must be a mapping")
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise SimError(f"{source}: unknown preset keys {unknown}")
        kwargs: dict[str, Any] = {}
        for k, v in data.items():
            default = getattr(cls(), k)
            kwargs[k] = _coerce(v, default, f"{source}: {k}")
        return cls(**kwargs)

    @classmethod
    def from_yaml(cls, path: str | Path) -> SimPreset:
        try:
            data = read_yaml(path, "preset file")
        except ConfigError as exc:
            raise SimError(str(exc)) from None
        if isinstance(data, dict) and "base" in data:
            base = get_preset(str(data.pop("base"))).to_dict()
            base.update(data)
            data = base
        return cls.from_dict(data, source=str(path))

    def to_yaml(self, path: str | Path) -> None:
        write_yaml(path, self.to_dict())

    def replace(self, **changes: Any) -> SimPreset:
        return dataclasses.replace(self, **changes)


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise SimError(f"preset: {message}")


def _pair(v: tuple[float, float], name: str, lo: float, hi: float) -> None:
    _check(
        len(v) == 2 and lo <= v[0] <= v[1] <= hi, f"{name} must be [min, max] within [{lo}, {hi}]"
    )


def _coerce(value: Any, default: Any, where: str) -> Any:
    """Check a YAML value against the type of the field's default."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise SimError(f"{where} must be true or false")
        return value
    if isinstance(default, int) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, int):
            raise SimError(f"{where} must be an integer")
        return value
    if isinstance(default, float) or default is None:
        if value is None and default is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SimError(f"{where} must be a number")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise SimError(f"{where} must be a string")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)) or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value
        ):
            raise SimError(f"{where} must be a list of numbers")
        return tuple(float(x) for x in value)
    raise SimError(f"{where}: unsupported value")  # pragma: no cover - all fields covered


#: Built-in presets. ``clean``: no noise or bias, global shutter, short exposure, moderate
#: smooth motion, guesses equal truth. ``realistic``: real hand shake, rolling shutter, 20 ms
#: exposure, MEMS gyro noise and bias, 5-30 ms offset, guesses a few % off. ``hard``: fast shake,
#: long exposure, saturation, a dense jittered grid larger than the view (crossing streaks, dots
#: leaving the frame).
PRESETS: dict[str, SimPreset] = {
    "clean": SimPreset(name="clean", dot_fill=0.85),
    "realistic": SimPreset(
        name="realistic",
        focal_spread=0.03,
        aspect_spread=0.003,
        principal_spread_px=12.0,
        exposure_s=0.02,
        readout_s=0.025,
        readout_spread=0.08,
        imu_rate_hz=200.0,
        gyro_noise_radps=0.005,
        gyro_bias_radps=0.02,
        gyro_scale_error=0.003,
        misalignment_deg=(1.0, 2.0),
        timeshift_s=(0.005, 0.030),
        motion="shake",
        motion_scale=(0.7, 1.3),
        motion_band_hz=(1.0, 15.0),
        dot_fill=0.88,
        dot_flux_eps=1.2e7,
        ambient_eps=4.0e4,
        vignetting=0.3,
        read_noise_e=8.0,
        shot_noise=True,
    ),
    "hard": SimPreset(
        name="hard",
        focal_spread=0.04,
        aspect_spread=0.005,
        principal_spread_px=20.0,
        fps=20.0,
        exposure_s=0.04,
        readout_s=0.03,
        readout_spread=0.1,
        imu_rate_hz=200.0,
        gyro_noise_radps=0.01,
        gyro_bias_radps=0.05,
        gyro_scale_error=0.01,
        misalignment_deg=(1.0, 2.0),
        timeshift_s=(0.005, 0.030),
        motion="shake",
        motion_scale=(2.0, 3.0),
        motion_band_hz=(1.0, 20.0),
        dot_cols=23,
        dot_rows=15,
        dot_fill=1.15,
        dot_jitter=0.3,
        dot_sigma_px=1.5,
        dot_flux_eps=4.0e7,
        ambient_eps=6.0e4,
        read_noise_e=12.0,
        shot_noise=True,
    ),
}


#: ``dense``: ``realistic`` optics and motion with a denser grid (20 x 15 dots, ~290 streaks per
#: 1280 x 720 frame) and a 1 kHz gyro: the speed benchmark's input (bench/bench_detect.py).
PRESETS["dense"] = PRESETS["realistic"].replace(
    name="dense", dot_cols=20, dot_rows=15, imu_rate_hz=1000.0
)


#: ``optics``: ``realistic`` seen through real optics: a red laser on an RGGB sensor (Bayer
#: mosaic, bilinear demosaicing), speckle, corners blurred, colour fringes, blooming and JPEG
#: (quality 85); brighter dots so that some saturate and bloom. ``phone``: the same, harder:
#: stronger speckle and lens blur, JPEG quality 70, a dense grid.
PRESETS["optics"] = PRESETS["realistic"].replace(
    name="optics",
    dot_flux_eps=2.0e7,
    speckle_contrast=0.25,
    speckle_px=1.2,
    lens_blur_px=1.0,
    chromatic_px=0.6,
    colour_response=(1.0, 0.18, 0.06),
    blooming=0.3,
    jpeg_quality=85,
)
PRESETS["phone"] = PRESETS["optics"].replace(
    name="phone",
    dot_cols=20,
    dot_rows=15,
    imu_rate_hz=1000.0,
    speckle_contrast=0.4,
    lens_blur_px=1.6,
    chromatic_px=1.0,
    jpeg_quality=70,
)


def get_preset(name: str) -> SimPreset:
    """A built-in preset by name (``clean``, ``realistic``, ``hard``, ``dense``, ...)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise SimError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}") from None
