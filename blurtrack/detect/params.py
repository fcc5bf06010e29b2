"""Parameters of streak detection (a frozen, self-validating dataclass with YAML I/O)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from blurtrack.detect.image import COLOURS
from blurtrack.detect.paramsections import (
    GyroPassParams,
    LinesParams,
    OrientationParams,
    QualityParams,
    SeparationParams,
    TimeshiftParams,
)
from blurtrack.errors import ConfigError
from blurtrack.io.atomic import write_text_atomic
from blurtrack.io.yamlio import dump_yaml, parse_yaml, yaml_error_line

__all__ = [
    "DetectParams",
    "GyroPassParams",
    "LinesParams",
    "OrientationParams",
    "QualityParams",
    "SeparationParams",
    "SourceParams",
    "TimeshiftParams",
]

#: The top level's numeric parameters (checked to be numbers before their ranges), and those
#: of them that may be None (measured or taken from the frame instead).
NUMBERS = (
    "smooth_sigma_px",
    "threshold_snr",
    "min_threshold",
    "min_area_px",
    "psf_sigma_px",
    "faint_snr",
    "hot_pixel_ratio",
    "saturation_level",
    "border_margin_px",
    "max_streaks",
    "artefact_ratio",
    "artefact_gap_px",
)
OPTIONAL_NUMBERS = ("psf_sigma_px", "saturation_level")


@dataclass(frozen=True)
class SourceParams:
    """Point light or extended source, and trustworthy ends (:mod:`blurtrack.detect.trust`).

    Every value is a ratio to the frame's own measured point spread or brightness, never a
    pixel count.

    - ``point_width_ratio``: a point light's cross-section sigma is the PSF's; up to this many
      PSF sigmas is still one (the frame's widths scatter around their median by ~10 %, and
      two dots overlapping side by side measure 1.5x: the ``merged`` flag's limit).
    - ``extended_width_ratio``: wider than this many PSF sigmas is an extended source (twice
      the PSF: no single dot, nor two dots half a PSF apart, measure that wide).
    - ``point_fill``: a point light's component lights at most this times the area its
      streaks would light as PSF-wide lines (crossings only lower the ratio; the margin
      covers the rounding of lit half-widths to whole pixels on short streaks).
    - ``extended_fill``: a lit region above this times that area is an extended source.
    - ``end_light_max``: light beyond an end (a cross-section integral 3 to 4 sigmas out,
      where it leaves the edge fit no dip to stop at) above this fraction of the streak's
      brightness at that end means a neighbour's light reaches the end: the end is not
      trusted.
    - ``gyro_vector_tol_px``, ``hairpin_depth_px`` (with a gyro,
      :mod:`blurtrack.detect.gyro.gyrotrust`): the two share the contract's 2 px end gate.
      The measured start-to-end vector may be off the gyro's prediction (corrected by the
      session's fitted first-order calibration error) by three quarters of it (an end ``e``
      px off moves the vector ``e``); the predicted start or end may lie from the path's
      extremity beyond it (a hairpin or a hook: the visible ends are the turns) by the
      quarter left.
    - ``gyro_confirm_tol_px`` (with a gyro): a streak the image doubts (a lit end, a blown-out
      core, a shape off the consensus, a crossing) is confirmed only where its vector is this
      near the prediction. The vector bounds the doubted end's error only up to the other
      end's own error, so that end's typical error (``plain_end_px``) comes off the vector's
      share: ``gyro_vector_tol_px`` - ``plain_end_px``.
    - ``end_gate_px``, ``plain_end_px`` (with a gyro): the contract's gate (``quality_ok`` ends
      within 2 px of the truth) and the typical error of an end the image measures plainly
      (the median of plain ends, 0.25 px: docs/detection.md). The two tolerances above hold
      against a prediction that is right; in a frame where it is not, a vector that matches it
      is off with it. The frame's model error is its plain streaks' median vector residual
      less their own ends' share, ``plain_end_px``; a residual ``r`` then bounds an end's
      error by ``r`` plus it, so the frame's vector tolerance is ``end_gate_px`` less it, at
      most ``gyro_vector_tol_px``, and its confirmation tolerance as much lower
      (:func:`blurtrack.detect.gyro.framecheck.frame_tolerances`).
    """

    point_width_ratio: float = 1.5
    extended_width_ratio: float = 2.0
    point_fill: float = 1.5
    extended_fill: float = 3.0
    end_light_max: float = 0.2
    gyro_vector_tol_px: float = 1.5
    hairpin_depth_px: float = 0.5
    gyro_confirm_tol_px: float = 1.25
    end_gate_px: float = 2.0
    plain_end_px: float = 0.25

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"detect source.{f.name} must be positive, got {v!r}")
        if not self.point_width_ratio <= self.extended_width_ratio:
            raise ConfigError(
                "detect source.point_width_ratio must not exceed extended_width_ratio"
            )
        if not self.point_fill <= self.extended_fill:
            raise ConfigError("detect source.point_fill must not exceed extended_fill")
        if not self.gyro_confirm_tol_px <= self.gyro_vector_tol_px:
            raise ConfigError(
                "detect source.gyro_confirm_tol_px must not exceed gyro_vector_tol_px"
            )
        if not self.gyro_vector_tol_px <= self.end_gate_px:
            raise ConfigError("detect source.gyro_vector_tol_px must not exceed end_gate_px")
        if not self.plain_end_px < self.end_gate_px:
            raise ConfigError("detect source.plain_end_px must be less than end_gate_px")


@dataclass(frozen=True)
class DetectParams:
    """Tuning of :func:`blurtrack.detect.detect_frame`.

    Intensities are relative to the image's full scale (0..1 after conversion); lengths in px.

    - ``smooth_sigma_px``: Gaussian pre-smoothing (noise suppression) before thresholding and
      profile sampling; it widens every edge by the same known amount.
    - ``threshold_snr``: segmentation threshold in units of the smoothed image's noise.
    - ``min_threshold``: absolute floor of that threshold (full-scale units).
    - ``min_area_px``: smallest connected component kept.
    - ``psf_sigma_px``: dot spread sigma; ``None`` estimates it per frame from the streaks.
    - ``faint_snr``: streaks whose peak is below this many noise sigmas are flagged ``faint``.
    - ``hot_pixel_ratio``: a pixel brighter than its brightest 8-neighbour by this factor
      (above background) is a hot pixel and is replaced by that neighbour.
    - ``saturation_level``: raw value treated as saturated (``None``: the dtype's maximum).
    - ``colour``: how a colour frame becomes one channel (:func:`blurtrack.detect.image.to_gray`):
      ``auto``, the luma of the frame's light where that light is one colour (a laser), else
      the brightest channel per pixel; ``max``, always the brightest channel per pixel.
    - ``border_margin_px``: endpoints closer than this to the border are flagged ``clipped``.
    - ``max_streaks``: hard cap of streaks per frame (bad input guard).
    - ``artefact_ratio``, ``artefact_gap_px``: a component whose peak is below
      ``artefact_ratio`` times that of a component within ``artefact_gap_px`` is dropped as an
      artefact of it (JPEG ringing, demosaicing, blooming); 0 keeps every component.
    - ``separate``: separate touching and overlapping streaks with the frame's own clean
      streaks as templates (:mod:`blurtrack.detect.separation.separate`).
    - ``gyro_template``: in a session with a gyro, a second pass on frames of hairpin
      streaks with the gyro's predicted curve as the template
      (:mod:`blurtrack.detect.gyro.gyropass`).
    - ``source``: point light or extended source, trustworthy ends (:class:`SourceParams`).
    - ``lines``, ``separation``, ``quality``, ``gyro_pass``, ``orientation``, ``timeshift``:
      each stage's tuning
      (:mod:`blurtrack.detect.paramsections`).

    In YAML every section is a nested mapping (any of its keys may be left out).
    """

    smooth_sigma_px: float = 1.0
    threshold_snr: float = 6.0
    min_threshold: float = 0.01
    min_area_px: int = 6
    psf_sigma_px: float | None = None
    faint_snr: float = 25.0
    hot_pixel_ratio: float = 3.0
    saturation_level: float | None = None
    colour: str = "auto"
    border_margin_px: float = 2.0
    max_streaks: int = 5000
    artefact_ratio: float = 0.06
    artefact_gap_px: int = 12
    separate: bool = True
    gyro_template: bool = True
    source: SourceParams = field(default_factory=SourceParams)
    lines: LinesParams = field(default_factory=LinesParams)
    separation: SeparationParams = field(default_factory=SeparationParams)
    quality: QualityParams = field(default_factory=QualityParams)
    gyro_pass: GyroPassParams = field(default_factory=GyroPassParams)
    orientation: OrientationParams = field(default_factory=OrientationParams)
    timeshift: TimeshiftParams = field(default_factory=TimeshiftParams)

    def __post_init__(self) -> None:
        for name in NUMBERS:
            value = getattr(self, name)
            if value is None and name in OPTIONAL_NUMBERS:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"detect parameter {name} must be a number, got {value!r}")
        positive = ("smooth_sigma_px", "threshold_snr", "faint_snr", "hot_pixel_ratio")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):  # a number: NUMBERS checked above
                raise ConfigError(f"detect parameter {name} must be positive, got {value!r}")
        if not (math.isfinite(self.min_threshold) and self.min_threshold >= 0):
            raise ConfigError(f"detect min_threshold must be >= 0: {self.min_threshold!r}")
        if self.psf_sigma_px is not None and not (0.3 <= self.psf_sigma_px <= 10.0):
            raise ConfigError(f"detect psf_sigma_px not in [0.3, 10]: {self.psf_sigma_px!r}")
        if self.saturation_level is not None and not self.saturation_level > 0:
            raise ConfigError("detect parameter saturation_level must be positive")
        if self.colour not in COLOURS:
            raise ConfigError(f"detect parameter colour must be one of {COLOURS}: {self.colour!r}")
        if int(self.min_area_px) != self.min_area_px or self.min_area_px < 1:
            raise ConfigError(f"detect min_area_px must be an integer >= 1: {self.min_area_px!r}")
        if not self.border_margin_px >= 0:
            raise ConfigError("detect parameter border_margin_px must be >= 0")
        if not (math.isfinite(self.artefact_ratio) and 0.0 <= self.artefact_ratio < 1.0):
            raise ConfigError(f"detect artefact_ratio not in [0, 1): {self.artefact_ratio!r}")
        if int(self.artefact_gap_px) != self.artefact_gap_px or self.artefact_gap_px < 0:
            raise ConfigError(
                f"detect artefact_gap_px must be an integer >= 0: {self.artefact_gap_px!r}"
            )
        if not isinstance(self.separate, bool):
            raise ConfigError(f"detect parameter separate must be true or false: {self.separate!r}")
        if not isinstance(self.gyro_template, bool):
            raise ConfigError(
                f"detect parameter gyro_template must be true or false: {self.gyro_template!r}"
            )
        if int(self.max_streaks) != self.max_streaks or self.max_streaks < 1:
            raise ConfigError("detect parameter max_streaks must be a positive integer")
        for name, kind in _sections().items():
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(
                    f"detect parameter {name} must be a mapping: {getattr(self, name)!r}"
                )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DetectParams:
        data = dict(_checked_keys(data, cls, "detect parameter"))
        for name, kind in _sections().items():
            if name in data:
                sec = _checked_keys(data[name], kind, f"detect {name} parameter")
                try:
                    data[name] = kind(**sec)
                except TypeError as exc:
                    raise ConfigError(f"invalid detect {name} parameters: {exc}") from exc
        try:
            return cls(**data)
        except TypeError as exc:  # wrong value types surface here
            raise ConfigError(f"invalid detect parameters: {exc}") from exc

    def to_yaml(self, path: str | Path) -> None:
        write_text_atomic(path, dump_yaml(self.to_dict(), sort_keys=True))

    @classmethod
    def from_yaml(cls, path: str | Path) -> DetectParams:
        try:
            data = parse_yaml(Path(path).read_text())
        except OSError as exc:
            raise ConfigError(f"cannot read detect parameters {path}: {exc.strerror}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(
                f"detect parameters {path} are not valid YAML: {yaml_error_line(exc)}"
            ) from None
        return cls.from_dict(data or {})


def _sections() -> dict[str, type]:
    """The nested sections of :class:`DetectParams`: YAML key -> dataclass."""
    return {
        "source": SourceParams,
        "lines": LinesParams,
        "separation": SeparationParams,
        "quality": QualityParams,
        "gyro_pass": GyroPassParams,
        "orientation": OrientationParams,
        "timeshift": TimeshiftParams,
    }


def _checked_keys(data: Any, cls: type, what: str) -> dict[str, Any]:
    """``data`` as a mapping holding only ``cls``'s field names; else one-line ConfigError
    (``what``: e.g. "detect parameter", named in the message)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{what}s must be a mapping")
    unknown = sorted(set(data) - {f.name for f in fields(cls)})
    if unknown:
        raise ConfigError(f"unknown {what}(s): {', '.join(unknown)}")
    return data
