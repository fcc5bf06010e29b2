"""``sensor_msgs/Image`` and ``CompressedImage`` payloads to and from numpy images.

Session images are OpenCV arrays: ``(H, W)`` gray or ``(H, W, 3)`` BGR, uint8 or uint16. ROS
images carry an ``encoding`` (REP 118 names), ``step`` (bytes per row) and ``is_bigendian``.
Everything read from a message is range-checked before any array is shaped from it.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from blurtrack.errors import ImportFormatError

#: Largest image side accepted from a message (px).
MAX_SIDE_PX = 16384
#: Largest compressed payload accepted (bytes).
MAX_COMPRESSED_BYTES = 256 * 1024**2

#: encoding -> (channels, dtype, conversion to the session's BGR/gray or None)
_ENCODINGS: dict[str, tuple[int, type, int | None]] = {
    "mono8": (1, np.uint8, None),
    "8UC1": (1, np.uint8, None),
    "mono16": (1, np.uint16, None),
    "16UC1": (1, np.uint16, None),
    "bgr8": (3, np.uint8, None),
    "8UC3": (3, np.uint8, None),
    "rgb8": (3, np.uint8, cv2.COLOR_RGB2BGR),
    "bgra8": (4, np.uint8, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, np.uint8, cv2.COLOR_RGBA2BGR),
    "bgr16": (3, np.uint16, None),
    "rgb16": (3, np.uint16, cv2.COLOR_RGB2BGR),
}


def check_size(width: int, height: int, where: str) -> None:
    if not (0 < int(width) <= MAX_SIDE_PX and 0 < int(height) <= MAX_SIDE_PX):
        raise ImportFormatError(
            f"{where}: image size {width}x{height} is outside 1..{MAX_SIDE_PX} px"
        )


def encode_raw(image: np.ndarray) -> tuple[str, int, bytes]:
    """``(encoding, step, data)`` of a session image: gray -> mono8/mono16, BGR -> rgb8/rgb16
    (Kalibr and Foxglove read both); little-endian."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16) or img.ndim not in (2, 3):
        raise ImportFormatError(f"cannot encode a {img.dtype} image of shape {img.shape}")
    bits = 8 if img.dtype == np.uint8 else 16
    if img.ndim == 2:
        enc = f"mono{bits}"
    else:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB)
        enc = f"rgb{bits}"
    img = np.ascontiguousarray(img.astype(img.dtype.newbyteorder("<"), copy=False))
    return enc, int(img.strides[0]), img.tobytes()


def decode_raw(
    width: int, height: int, encoding: str, is_bigendian: int, step: int, data: np.ndarray
) -> np.ndarray:
    """A ``sensor_msgs/Image`` payload as a session image (gray or BGR, uint8/uint16)."""
    check_size(width, height, "sensor_msgs/Image")
    if encoding not in _ENCODINGS:
        raise ImportFormatError(
            f"sensor_msgs/Image encoding {encoding!r} is not supported "
            f"(supported: {', '.join(_ENCODINGS)})"
        )
    ch, dtype, conv = _ENCODINGS[encoding]
    item = np.dtype(dtype).itemsize
    row = width * ch * item
    buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if step < row or step > 4 * row + 64 or buf.size < step * (height - 1) + row:
        raise ImportFormatError(
            f"sensor_msgs/Image {width}x{height} {encoding}: step {step} and "
            f"{buf.size} data bytes do not fit"
        )
    if buf.size < step * height:
        buf = np.concatenate([buf, np.zeros(step * height - buf.size, np.uint8)])
    rows = buf[: step * height].reshape(height, step)[:, :row]
    order: Literal[">", "<"] = ">" if is_bigendian else "<"
    img = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order))
    img = img.reshape(height, width, ch).astype(dtype)
    if ch == 1:
        return img[..., 0]
    return cv2.cvtColor(img, conv) if conv is not None else img


def decode_compressed(fmt: str, data: np.ndarray) -> np.ndarray:
    """A ``sensor_msgs/CompressedImage`` payload (JPEG/PNG) as a session image."""
    buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if buf.size > MAX_COMPRESSED_BYTES:
        raise ImportFormatError(f"CompressedImage of {buf.size} bytes is too large")
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImportFormatError(f"CompressedImage ({fmt!r}) does not decode")
    check_size(img.shape[1], img.shape[0], "CompressedImage")
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img
