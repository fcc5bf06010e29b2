"""Exception hierarchy of the gamd package.

Every error that bad input can cause in ``gamd`` derives from :class:`GamdError`, itself a
:class:`blurtrack.errors.BlurTrackError`, so both CLIs turn it into one line and exit 2.
"""

from __future__ import annotations

from blurtrack.errors import BlurTrackError


class GamdError(BlurTrackError):
    """Base class of every gamd error (bad config, dataset, checkpoint or input)."""


class GamdConfigError(GamdError):
    """A network, data or training configuration is invalid."""


class GamdDataError(GamdError):
    """A dataset folder, image or heat map is missing or malformed."""


class CheckpointError(GamdError):
    """A checkpoint file is missing, corrupt or incompatible."""
