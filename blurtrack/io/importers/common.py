"""Shared helpers of the importers: bounded text reads, image reads, 4x4 transforms."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from blurtrack.errors import ImportFormatError

MAX_TEXT_BYTES = 256 * 1024**2


def text_lines(path: Path) -> list[str]:
    if not path.is_file():
        raise ImportFormatError(f"missing file: {path}")
    if path.stat().st_size > MAX_TEXT_BYTES:
        raise ImportFormatError(f"{path} is larger than {MAX_TEXT_BYTES} bytes")
    return path.read_text(encoding="utf-8", errors="strict").splitlines()


def read_image(path: Path) -> np.ndarray:
    if not path.is_file():
        raise ImportFormatError(f"missing image: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImportFormatError(f"image {path} does not decode")
    return img


def T_from_R(R: np.ndarray) -> list[list[float]]:
    T = np.eye(4)
    T[:3, :3] = R
    return T.tolist()
