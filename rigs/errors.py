"""Exception hierarchy of the rigs package.

Every error derives from :class:`RigError`, itself a :class:`blurtrack.errors.BlurTrackError`,
so the ``blurtrack`` CLI turns any of them into one line on stderr and exit status 2.
"""

from __future__ import annotations

from blurtrack.errors import BlurTrackError


class RigError(BlurTrackError):
    """Base class of every recording-rig error."""


class DeviceUrlError(RigError):
    """A device URL is malformed or names an unknown scheme or option."""


class DeviceError(RigError):
    """A device could not be opened or failed while streaming."""


class DeviceDisconnectedError(DeviceError):
    """A device disappeared (unplugged, port closed) while streaming."""


class ProtocolError(RigError):
    """Bytes or values that cannot be encoded in, or decoded from, the IMU protocol."""


class TimeSyncError(RigError):
    """Too few or inconsistent samples to map device time onto host time."""


class RecorderLogError(RigError):
    """A recorder log is unreadable, of the wrong format, or holds no usable data."""


class RigConfigError(RigError, ValueError):
    """A configuration dataclass got an invalid value (also a ValueError)."""
