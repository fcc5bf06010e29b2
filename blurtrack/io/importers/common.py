"""Shared helpers of the importers: bounded text reads, image reads, 4x4 transforms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.io.images import ImageError
from blurtrack.io.images import read_image as read_checked_image

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
    try:
        return read_checked_image(path)  # size checked from the header before decoding
    except ImageError as exc:
        raise ImportFormatError(str(exc)) from None


def T_from_R(R: np.ndarray) -> list[list[float]]:
    T = np.eye(4)
    T[:3, :3] = R
    return T.tolist()


#: Longest exposure accepted from an option (s).
MAX_EXPOSURE_S = 10.0
#: Most frames one import takes.
MAX_FRAMES = 1_000_000
STAMPS = ("start", "middle")


def exposure_ns(exposure_s: float | None, kind: str) -> int:
    """The frame exposure from the ``--exposure-ms`` option, range-checked."""
    if exposure_s is None:
        raise ImportFormatError(
            f"{kind}: the recording does not state the exposure; give --exposure-ms"
        )
    e = float(exposure_s)
    if not (np.isfinite(e) and 0.0 < e <= MAX_EXPOSURE_S):
        raise ImportFormatError(f"{kind}: exposure {e} s is outside (0, {MAX_EXPOSURE_S}] s")
    return max(1, round(e * 1e9))


def check_readout(readout_s: float, kind: str) -> float:
    r = float(readout_s)
    if not (np.isfinite(r) and 0.0 <= r <= 1.0):
        raise ImportFormatError(f"{kind}: readout {r} s is outside [0, 1] s")
    return r


def frame_start_ns(stamp_ns: int, stamp: str, exp_ns: int, readout_s: float) -> int:
    """Session time (start of the top row's exposure) of a frame stamped at ``stamp``:
    ``start`` as is, ``middle`` the centre of the frame's exposure (mid row, mid exposure)."""
    if stamp not in STAMPS:
        raise ImportFormatError(f"stamp must be one of {STAMPS}, got {stamp!r}")
    if stamp == "start":
        return int(stamp_ns)
    return int(stamp_ns) - (exp_ns + round(readout_s * 1e9)) // 2


def rate_hz(t_ns: np.ndarray, where: str) -> float:
    d = np.diff(np.asarray(t_ns, np.int64))
    d = d[d > 0]
    if d.size == 0:
        raise ImportFormatError(f"{where}: fewer than 2 distinct IMU timestamps")
    return float(1e9 / float(np.median(d)))


def sorted_unique(t_ns: np.ndarray) -> np.ndarray:
    """Indices that sort ``t_ns`` and drop repeated stamps (first kept)."""
    order = np.argsort(t_ns, kind="stable")
    keep = np.r_[True, np.diff(np.asarray(t_ns)[order]) > 0]
    return order[keep]


def guessed_intrinsics(width: int, height: int) -> tuple[float, float, float, float]:
    """A stated guess when a source gives no intrinsics: fx = fy = width (about 53 degrees
    horizontal field of view), principal point at the centre; calibration refines it."""
    return (float(width), float(width), (width - 1) / 2.0, (height - 1) / 2.0)
