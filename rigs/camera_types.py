"""The frame record that every camera source returns."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from rigs.errors import DeviceError


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


def image_info(image: np.ndarray) -> tuple[int, int, int]:
    """(width, height, channels) of an image array; DeviceError if it is not one."""
    if image.dtype not in (np.uint8, np.uint16):
        raise DeviceError(f"camera delivered {image.dtype} pixels, not uint8/uint16")
    if image.ndim == 2:
        return image.shape[1], image.shape[0], 1
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        return image.shape[1], image.shape[0], image.shape[2]
    raise DeviceError(f"camera delivered an array of shape {image.shape}, not an image")
