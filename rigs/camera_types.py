"""The frame record that every camera source returns."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class CameraFrame:
    """One grabbed frame.

    image: (H, W) or (H, W, 3) BGR, uint8 or uint16. timestamp_ns: start of exposure of the
    first row on the host monotonic clock (the driver's stamp where it has one, else host time
    at grab). exposure_ns: -1 when the camera does not report it. host_ns: host time at grab.
    stamp_source: "driver" or "host".
    """

    index: int
    image: np.ndarray
    timestamp_ns: int
    exposure_ns: int
    host_ns: int
    stamp_source: str


class CameraSource(Protocol):
    """What the recorder needs from a camera."""

    url: str
    frames_dropped: int

    def read(self) -> CameraFrame | None:
        """The next frame; None when the stream has ended."""
        ...

    def close(self) -> None: ...
