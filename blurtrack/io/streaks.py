"""The streak table: measured (or true) blur trajectories of laser dots, one row per streak.

Written by ``blurtrack detect`` (Parquet), read by calibration and reports. Columns:

=====================  ==========  ==========================================================
column                 type        meaning
=====================  ==========  ==========================================================
frame                  int64       index of the frame in the session's cam0/data.csv
timestamp_ns           int64       the frame's timestamp (camera clock)
streak_id              int64       streak number within the frame
start_x, start_y       float64     start of exposure endpoint (px, DESIGN pixel convention)
end_x, end_y           float64     end of exposure endpoint (px)
length_px              float64     arc length of the centre line (px)
centerline             list        ordered ``[[x, y], ...]`` from start to end, ~1 px apart
profile                list        brightness along the centre line (same length)
orientation_confidence float64     0..1: how sure the start/end assignment is
orientation_source     string      ``gyro``, ``continuity``, ``profile``, ``truth`` or ``none``
clipped                bool        touches the image border
saturated              bool        has saturated pixels
merged                 bool        merged with or crossing another streak
faint                  bool        low contrast
shape_deviation_px     float64     optional: start-to-end vector's distance from the frame's
                                   consensus (px; NaN unknown)
quality_ok             bool        optional: fit for calibration (:func:`usable`)
=====================  ==========  ==========================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.errors import BlurTrackError
from blurtrack.io import atomic

#: Largest endpoint coordinate accepted (px): the largest camera side (geometry.camera).
MAX_COORD_PX = 65536

COLUMNS: dict[str, str] = {
    "frame": "int64",
    "timestamp_ns": "int64",
    "streak_id": "int64",
    "start_x": "float64",
    "start_y": "float64",
    "end_x": "float64",
    "end_y": "float64",
    "length_px": "float64",
    "centerline": "object",
    "profile": "object",
    "orientation_confidence": "float64",
    "orientation_source": "object",
    "clipped": "bool",
    "saturated": "bool",
    "merged": "bool",
    "faint": "bool",
}
FLAG_COLUMNS = ("clipped", "saturated", "merged", "faint")
#: Optional quality columns (``blurtrack detect`` writes them, older tables lack them; checked
#: when present, and :func:`usable` works either way): distance of the streak's start-to-end
#: vector from its frame's consensus (px, NaN = unknown), and whether the streak is fit for
#: calibration.
OPTIONAL_COLUMNS: dict[str, str] = {"shape_deviation_px": "float64", "quality_ok": "bool"}


def usable(df: pd.DataFrame) -> pd.Series:
    """Streaks fit for calibration: ``quality_ok`` where the table has it, else (older tables)
    neither ``clipped`` nor ``merged``."""
    if "quality_ok" in df.columns:
        return df["quality_ok"].astype(bool)
    return ~(df["clipped"].astype(bool) | df["merged"].astype(bool))


class StreakTableError(BlurTrackError):
    """A streak table is missing columns or holds invalid values."""


def validate(df: pd.DataFrame) -> pd.DataFrame:
    """Check columns and values; returns the frame with canonical dtypes."""
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise StreakTableError(f"streak table lacks columns {missing}")
    out = df.copy()
    for c, dt in COLUMNS.items():
        if dt != "object":
            try:
                out[c] = out[c].astype(dt)
            except (TypeError, ValueError) as exc:
                raise StreakTableError(f"streak table column {c!r}: {exc}") from None
    for c, dt in OPTIONAL_COLUMNS.items():
        if c in out.columns:
            try:
                out[c] = out[c].astype(dt)
            except (TypeError, ValueError) as exc:
                raise StreakTableError(f"streak table column {c!r}: {exc}") from None
    xy = out[["start_x", "start_y", "end_x", "end_y"]].to_numpy(float)
    if not np.all(np.isfinite(xy)):
        raise StreakTableError("streak table has NaN or infinite endpoints")
    if xy.size and np.abs(xy).max() > MAX_COORD_PX:
        raise StreakTableError(
            f"streak table has endpoints {np.abs(xy).max():.4g} px from the origin "
            f"(beyond {MAX_COORD_PX} px: not from any camera image)"
        )
    return out


def check_matches_session(df: pd.DataFrame, frames: pd.DataFrame, resolution: Any) -> None:
    """Refuse a table of another (or an older) recording: frame numbers, timestamps and image
    bounds must match the session's ``frames`` (``Session.frames``) and ``resolution``."""
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    idx = df["frame"].to_numpy(np.int64)
    if np.any((idx < 0) | (idx >= ts.size)):
        raise StreakTableError(f"streak table names frames outside 0..{ts.size - 1}")
    if np.any(df["timestamp_ns"].to_numpy(np.int64) != ts[idx]):
        raise StreakTableError(
            "streak table timestamps do not match the session's cam0/data.csv "
            "(a stale table or another recording: run detect again)"
        )
    w, h = (int(v) for v in resolution)
    xy = df[["start_x", "start_y", "end_x", "end_y"]].to_numpy(float)
    if xy.size and (
        np.any(xy[:, ::2] < -w) | np.any(xy[:, ::2] > 2 * w)
        or np.any(xy[:, 1::2] < -h) | np.any(xy[:, 1::2] > 2 * h)
    ):
        raise StreakTableError(f"streak table has endpoints far outside the {w}x{h} frames")


#: Columns whose values repeat from row to row: Parquet dictionary-encodes only these. Tried
#: on the float and list columns the encoding is abandoned, at twice the writing time (dense
#: 720p session, 29 756 streaks: 0.10 -> 0.055 s, 13.4 -> 12.0 MB; the same values read back).
DICTIONARY_COLUMNS = ("frame", "timestamp_ns", "orientation_source")


def parquet_options(columns: Sequence[str]) -> dict[str, Any]:
    """Writer options (pyarrow's ``write_table`` keywords) for a table with ``columns``."""
    return {
        "compression": "snappy",
        "use_dictionary": [c for c in DICTIONARY_COLUMNS if c in columns],
    }


def write(df: pd.DataFrame, path: str | Path) -> None:
    """Write a validated table as Parquet (atomically)."""
    table = validate(df)
    opts = parquet_options(list(table.columns))
    # a file handle, not a path: pyarrow cannot encode non-UTF-8 file names
    atomic.write_atomic(path, lambda f: table.to_parquet(f, index=False, **opts))


def read(path: str | Path) -> pd.DataFrame:
    p = Path(path)
    if not p.is_file():
        raise StreakTableError(f"streak table not found: {p}")
    try:
        with open(p, "rb") as f:  # a handle: pyarrow cannot encode non-UTF-8 file names
            df = pd.read_parquet(f)
    except Exception as exc:  # pyarrow raises several unrelated types on corrupt files
        raise StreakTableError(
            f"streak table {p} is not readable Parquet: {str(exc).splitlines()[0]}"
        ) from None
    return validate(df)


def empty() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=dt) for c, dt in COLUMNS.items()})


def from_truth(truth: dict[str, Any], inside_only: bool = True) -> pd.DataFrame:
    """The simulator's true streaks (``truth.yaml`` ``frames``) as a streak table, with the
    time midpoints ``mid_x``, ``mid_y`` (NaN where the truth has none)."""
    try:
        rows = []
        for fr in truth["frames"]:
            for k, s in enumerate(fr["streaks"]):
                if inside_only and not s.get("inside", True):
                    continue
                cl = [[float(x), float(y)] for x, y in s["centerline"]]
                seg = np.diff(np.asarray(cl, float), axis=0) if len(cl) > 1 else np.zeros((0, 2))
                rows.append(
                    {
                        "frame": int(fr["index"]),
                        "timestamp_ns": int(fr["timestamp_ns"]),
                        "streak_id": int(s.get("dot", k)),
                        "start_x": float(s["start"][0]),
                        "start_y": float(s["start"][1]),
                        "end_x": float(s["end"][0]),
                        "end_y": float(s["end"][1]),
                        "length_px": float(np.linalg.norm(seg, axis=1).sum()),
                        "centerline": cl,
                        "profile": [1.0] * len(cl),
                        "orientation_confidence": 1.0,
                        "orientation_source": "truth",
                        "clipped": not s.get("inside", True),
                        "saturated": False,
                        "merged": False,
                        "faint": False,
                        "mid_x": float(s["mid"][0]) if "mid" in s else np.nan,
                        "mid_y": float(s["mid"][1]) if "mid" in s else np.nan,
                    }
                )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise StreakTableError(f"truth.yaml has no usable streak truth ({exc!r})") from None
    return validate(pd.DataFrame(rows, columns=[*COLUMNS, "mid_x", "mid_y"])) if rows else empty()
