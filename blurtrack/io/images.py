"""The one image reader and writer: header dimensions checked before decoding, bytes-safe paths.

:func:`read_image` reads the file's bytes itself (any :class:`~pathlib.Path`, including names
with bytes that are not UTF-8), reads the width and height from the PNG, JPEG or TIFF header
without decoding, refuses images over :data:`MAX_PIXELS` (a 100000² PNG header, a real 32000²
PNG that would decode to gigabytes), and only then decodes with ``cv2.imdecode``. OpenCV never
sees a path: ``cv2.imread``/``cv2.imwrite`` crash the process (SIGSEGV) on a ``str`` holding
surrogate-escaped bytes, which is how Python spells a non-UTF-8 file name.

:func:`write_image` encodes in memory and writes through :mod:`blurtrack.io.atomic`.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError
from blurtrack.io import atomic

#: Largest image decoded (pixels): 100 MP, above any camera frame or photograph we use.
MAX_PIXELS = 100_000_000
#: Largest image file read (bytes).
MAX_IMAGE_BYTES = 1 << 30


class ImageError(BlurTrackError):
    """An image file is missing, unreadable, malformed or too large."""


def _png_size(data: bytes) -> tuple[int, int] | None:
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    w, h = struct.unpack(">II", data[16:24])
    return int(w), int(h)


#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic ...).
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length field
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _SOF:
            if i + 9 > n:
                return None
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return int(w), int(h)
        if marker == 0xD9 or length < 2:
            return None
        i += 2 + length
    return None


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    end = "<" if data[:2] == b"II" else ">"
    if len(data) < 8:
        return None
    (magic,) = struct.unpack(end + "H", data[2:4])
    if magic != 42:  # BigTIFF (43) is not a frame format we read
        return None
    (ifd,) = struct.unpack(end + "I", data[4:8])
    if ifd + 2 > len(data):
        return None
    (count,) = struct.unpack(end + "H", data[ifd : ifd + 2])
    size: dict[int, int] = {}
    for k in range(count):
        e = ifd + 2 + 12 * k
        if e + 12 > len(data):
            return None
        tag, typ = struct.unpack(end + "HH", data[e : e + 4])
        if tag in (256, 257):
            fmt = "H" if typ == 3 else "I"
            (size[tag],) = struct.unpack(end + fmt, data[e + 8 : e + 8 + struct.calcsize(fmt)])
    if 256 in size and 257 in size:
        return size[256], size[257]
    return None


def header_size(data: bytes) -> tuple[str, tuple[int, int] | None]:
    """``(format, (width, height))`` from an image file's first bytes; size None if unreadable.

    Formats: ``png``, ``jpeg``, ``tiff``; anything else is ``unknown``.
    """
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "png", _png_size(data)
    if data[:2] == b"\xff\xd8":
        return "jpeg", _jpeg_size(data)
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff", _tiff_size(data)
    return "unknown", None


def read_image(
    path: str | os.PathLike[str],
    flags: int = cv2.IMREAD_UNCHANGED,
    max_pixels: int = MAX_PIXELS,
    what: str = "image",
) -> np.ndarray:
    """Decode a PNG, JPEG or TIFF file after checking its header's size against ``max_pixels``.

    Returns what ``cv2.imdecode(..., flags)`` returns (uint8/uint16, ``(H, W)`` or
    ``(H, W, C)`` BGR). Raises :class:`ImageError` (one line) for a missing, unreadable,
    truncated, oversized or undecodable file.
    """
    p = Path(path)
    name = os.fsdecode(p)
    try:
        size = p.stat().st_size
        if size > MAX_IMAGE_BYTES:
            raise ImageError(f"{what} {name!r} is {size} bytes, over {MAX_IMAGE_BYTES}")
        with open(p, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise ImageError(f"{what} not found: {name!r}") from None
    except OSError as exc:
        raise ImageError(f"cannot read {what} {name!r}: {exc.strerror or exc}") from None
    return decode_image(data, flags, max_pixels, f"{what} {name!r}")


def decode_image(
    data: bytes,
    flags: int = cv2.IMREAD_UNCHANGED,
    max_pixels: int = MAX_PIXELS,
    what: str = "image",
) -> np.ndarray:
    """Decode an encoded PNG, JPEG or TIFF (bytes) after the header's size check.

    ``what`` names the image in error messages (a path, ``frame 123``).
    """
    kind, dims = header_size(data)
    if kind == "unknown":
        raise ImageError(f"{what} does not decode: not a PNG, JPEG or TIFF file")
    if dims is None:
        raise ImageError(f"{what} does not decode: malformed {kind.upper()} header")
    w, h = dims
    if w <= 0 or h <= 0:
        raise ImageError(f"{what}: header says {w}x{h} pixels")
    if w * h > max_pixels:
        raise ImageError(f"{what} is {w}x{h} = {w * h} pixels, over the {max_pixels}-pixel limit")
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error:
        img = None
    if img is None:
        raise ImageError(f"{what} does not decode: truncated or corrupt {kind.upper()}")
    if img.shape[:2] != (h, w):
        raise ImageError(f"{what} decodes to {img.shape[1]}x{img.shape[0]}, header says {w}x{h}")
    return img


def write_image(
    path: str | os.PathLike[str], image: np.ndarray, params: list[int] | None = None
) -> Path:
    """Encode ``image`` by the path's suffix (``.png``, ``.jpg``, ``.tif``) and write it
    atomically; bytes-safe path, umask permissions, no debris on error."""
    p = Path(path)
    try:
        ok, buf = cv2.imencode(p.suffix or ".png", np.asarray(image), params or [])
    except cv2.error:
        ok = False
    if not ok:
        raise ImageError(f"cannot encode {os.fsdecode(p)!r} as {p.suffix or '.png'}")
    return atomic.write_bytes_atomic(p, buf.tobytes())
