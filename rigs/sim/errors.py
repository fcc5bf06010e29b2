"""Errors of the simulated rig."""

from __future__ import annotations

from blurtrack.errors import BlurTrackError


class SimError(BlurTrackError):
    """Bad simulator parameters or an impossible simulation request."""
