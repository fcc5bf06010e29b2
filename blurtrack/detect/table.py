"""The streak table of a session (schema: :mod:`blurtrack.io.streaks`, plus detection extras).

Extra columns beyond :data:`blurtrack.io.streaks.COLUMNS` (see docs/detection.md):
``crossing`` (the streak crosses another one), ``looped`` (it crosses itself), ``snr`` (peak
signal in noise sigmas), ``width_px`` (measured cross-section sigma in the pre-smoothed
image), ``start_brightness``/``end_brightness`` (profile plateau at each end), ``mid_x``,
``mid_y`` (time midpoint: where the dot was at mid-exposure), ``llr_gyro``,
``llr_profile``, ``llr_continuity`` (signed evidence that the recorded start is right),
``shape_deviation_px``, ``thick_saturated``, ``quality_ok`` (:mod:`blurtrack.detect.quality`).
The column ``merged`` of the core schema means "merged with or crossing another streak".
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.orientation import Orientation
from blurtrack.detect.quality import add_quality
from blurtrack.io import streaks

EXTRA_COLUMNS: dict[str, str] = {
    "crossing": "bool",
    "looped": "bool",
    "snr": "float64",
    "width_px": "float64",
    "start_brightness": "float64",
    "end_brightness": "float64",
    "mid_x": "float64",
    "mid_y": "float64",
    "llr_gyro": "float64",
    "llr_profile": "float64",
    "llr_continuity": "float64",
    "shape_deviation_px": "float64",
    "thick_saturated": "bool",
    "quality_ok": "bool",
}


def _nested_lists(arrays: Sequence[np.ndarray], decimals: int) -> list[list]:
    """Per-streak arrays rounded and turned into Python lists (one rounding and one
    ``tolist`` for the whole frame, then sliced)."""
    if not arrays:
        return []
    flat = np.round(np.concatenate(arrays), decimals).tolist()
    ends = np.cumsum([len(a) for a in arrays]).tolist()
    return [flat[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]


def frame_rows(frame: int, timestamp_ns: int, fs: FrameStreaks, ori: Orientation) -> pd.DataFrame:
    """The rows of one frame, ``fs`` already oriented (end A = start)."""
    N = len(fs)
    pts = _nested_lists(fs.points, 4)
    data = {
        "frame": np.full(N, frame, np.int64),
        "timestamp_ns": np.full(N, timestamp_ns, np.int64),
        "streak_id": np.arange(N, dtype=np.int64),
        "start_x": fs.end_a[:, 0],
        "start_y": fs.end_a[:, 1],
        "end_x": fs.end_b[:, 0],
        "end_y": fs.end_b[:, 1],
        "length_px": fs.length_px,
        "centerline": pts,
        "profile": _nested_lists(fs.profile, 6),
        "orientation_confidence": ori.confidence,
        "orientation_source": list(ori.source),
        "clipped": fs.flags["clipped"],
        "saturated": fs.flags["saturated"],
        "merged": fs.flags["merged"] | fs.flags["crossing"],
        "faint": fs.flags["faint"],
        "crossing": fs.flags["crossing"],
        "looped": fs.flags["looped"],
        "snr": fs.snr,
        "width_px": fs.width_px,
        "start_brightness": fs.plateau[:, 0],
        "end_brightness": fs.plateau[:, 1],
        "mid_x": fs.time_mid[:, 0],
        "mid_y": fs.time_mid[:, 1],
    }
    # Evidence for the recorded orientation (the LLRs were for the unswapped end A).
    signed = np.where(ori.swap[:, None], -ori.llr, ori.llr) if N else np.zeros((0, 3))
    data["llr_gyro"], data["llr_profile"], data["llr_continuity"] = signed.T
    return pd.DataFrame(data)


def build_table(parts: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Concatenate per-frame rows into a validated table (empty table if none)."""
    parts = [p for p in parts if len(p)]
    if not parts:
        df = streaks.empty()
        for c, dt in EXTRA_COLUMNS.items():
            df[c] = pd.Series(dtype=dt)
        return df
    df = add_quality(pd.concat(parts, ignore_index=True))
    return streaks.validate(df)


def write_table(df: pd.DataFrame, path: str | Path) -> None:
    """Write the table as Parquet, atomically (see :func:`blurtrack.io.streaks.write`)."""
    streaks.write(df, path)


def read_table(path: str) -> pd.DataFrame:
    """Read and validate a streak table."""
    return streaks.read(path)
