"""Exception hierarchy of the blurtrack package.

Every error that bad input can cause derives from :class:`BlurTrackError`; the CLI turns it into
a one-line message and a non-zero exit. The other packages (rigs, calib, gamd) derive their own
base classes from it so that the CLI layer catches them all in one place.
"""

from __future__ import annotations


class BlurTrackError(Exception):
    """Base class for every error raised on bad input or a failed operation."""


class SessionError(BlurTrackError):
    """A session folder is missing, malformed or inconsistent."""


class BoundsError(SessionError):
    """A session value lies outside its physical bound (blurtrack/io/bounds.py)."""


class ImportFormatError(BlurTrackError):
    """A third-party recording could not be imported."""


class GeometryError(BlurTrackError):
    """Invalid camera, rotation or trajectory parameters."""


class CoverageError(BlurTrackError):
    """Gyro samples do not cover the times that are asked for."""


class ConfigError(BlurTrackError):
    """A YAML configuration or parameter file is invalid."""


class DetectionError(BlurTrackError):
    """Streak detection failed on an input image."""


class SynthesisError(BlurTrackError):
    """Blur synthesis or dataset generation failed."""
