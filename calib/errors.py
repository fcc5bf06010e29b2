"""Exceptions of the calib package."""

from __future__ import annotations

from blurtrack.errors import BlurTrackError


class CalibError(BlurTrackError):
    """Calibration input is unusable or the fit cannot give a trustworthy answer."""


class AxisSearchError(CalibError):
    """The data cannot decide the camera–IMU axis mapping."""
