"""The one image reader: header sizes checked before decoding, bytes-safe paths."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.io import images


def _png_header(w: int, h: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (
        b"\x89PNG\r\n\x1a\n"
        + struct.pack(">I", len(ihdr))
        + chunk
        + struct.pack(">I", zlib.crc32(chunk))
    )


@pytest.mark.parametrize("ext", [".png", ".jpg", ".tif"])
def test_header_size_matches_decoder(tmp_path: Path, ext: str) -> None:
    img = (np.arange(37 * 53) % 251).astype(np.uint8).reshape(37, 53)
    p = images.write_image(tmp_path / f"a{ext}", img)
    kind, dims = images.header_size(p.read_bytes())
    assert dims == (53, 37), kind
    assert images.read_image(p).shape[:2] == (37, 53)


def test_huge_header_refused_before_decoding(tmp_path: Path) -> None:
    p = tmp_path / "huge.png"
    p.write_bytes(_png_header(100_000, 100_000) + b"\0" * 100)
    with pytest.raises(images.ImageError, match="over the 100000000-pixel limit"):
        images.read_image(p)
    # the limit is decided by the header, not by a decode
    ok = images.write_image(tmp_path / "ok.png", np.zeros((30, 40), np.uint8))
    with pytest.raises(images.ImageError, match="1200 pixels, over the 1000-pixel"):
        images.read_image(ok, max_pixels=1000)


@pytest.mark.parametrize(
    "data, match",
    [
        (b"", "not a PNG, JPEG or TIFF"),
        (b"GIF89a....", "not a PNG, JPEG or TIFF"),
        (b"\x89PNG\r\n\x1a\n", "malformed PNG header"),
        (b"\xff\xd8\xff\xe0\x00\x10JFIF", "malformed JPEG header"),
        (b"II*\x00\xff\xff\xff\xff", "malformed TIFF header"),
        (_png_header(0, 5), "header says 0x5"),
        (_png_header(40, 30) + b"garbage", "does not decode"),
    ],
)
def test_malformed_images(tmp_path: Path, data: bytes, match: str) -> None:
    p = tmp_path / "bad.png"
    p.write_bytes(data)
    with pytest.raises(images.ImageError, match=match) as ei:
        images.read_image(p)
    assert "\n" not in str(ei.value)


def test_non_utf8_path_does_not_crash(tmp_path: Path) -> None:
    folder = Path(os.fsdecode(os.fsencode(tmp_path) + b"/d\xff\xfe"))
    p = images.write_image(folder / "x.png", np.ones((4, 5), np.uint8))
    assert images.read_image(p).shape == (4, 5)
    with pytest.raises(images.ImageError, match="not found"):
        images.read_image(folder / "missing.png")


def test_missing_and_unwritable(tmp_path: Path) -> None:
    with pytest.raises(images.ImageError, match="not found"):
        images.read_image(tmp_path / "nope.png")
    with pytest.raises(images.ImageError, match="cannot encode"):
        images.write_image(tmp_path / "x.unknownext", np.zeros((2, 2), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_decode_via_cv2_agrees(tmp_path: Path) -> None:
    img = np.random.default_rng(0).integers(0, 65535, (9, 7, 3), dtype=np.uint16)
    p = images.write_image(tmp_path / "c.png", img)
    assert np.array_equal(images.read_image(p), cv2.imdecode(np.fromfile(p, np.uint8), -1))
