"""The streak table of a session (schema: :mod:`blurtrack.io.streaks`, plus detection extras).

Extra columns beyond :data:`blurtrack.io.streaks.COLUMNS` (see docs/detection.md):
``crossing`` (the streak crosses another one), ``looped`` (it crosses itself), ``snr`` (peak
signal in noise sigmas), ``width_px`` (measured cross-section sigma in the pre-smoothed
image), ``start_brightness``/``end_brightness`` (profile plateau at each end), ``mid_x``,
``mid_y`` (time midpoint: where the dot was at mid-exposure), ``gyro_residual_px`` (the
gyro check's start-to-end vector residual, NaN where not checked:
:mod:`blurtrack.detect.gyro.gyrotrust`), ``llr_gyro``,
``llr_profile``, ``llr_continuity`` (signed evidence that the recorded start is right),
``end_light_start``/``end_light_end`` (light just beyond each end over the streak's
brightness there, :mod:`blurtrack.detect.trust`), ``shape_deviation_px``,
``thick_saturated``, ``quality_ok``, ``source`` (``point``, ``extended``, ``undetermined``)
and ``reason`` (why not ``quality_ok``, or ``ok``) (:mod:`blurtrack.detect.separation.quality`).
The summary beside the table names its :data:`TABLE_VERSION` (``table_version``). The
column ``merged`` of the core schema means "merged with or crossing another streak".

In the table :func:`build_table` returns, a ``centerline`` cell is an ``(n, 2)`` float64 array
and a ``profile`` cell an ``(n,)`` one (views of one rounded array per frame: no per-value
Python floats); :func:`write_table` writes them as Parquet lists, the very file
``DataFrame.to_parquet`` writes from lists (and reading it back gives what it always gave).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import repeat
from operator import attrgetter, itemgetter
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.lines.ragged import split_at
from blurtrack.detect.separation.quality import QUALITY_COLUMNS, add_quality
from blurtrack.detect.session.orientation import Orientation
from blurtrack.io import atomic, streaks

#: Columns of the table beyond those of :mod:`blurtrack.io.streaks`, with their dtypes.
EXTRA_COLUMNS: dict[str, str] = {
    "crossing": "bool",
    "looped": "bool",
    "snr": "float64",
    "width_px": "float64",
    "start_brightness": "float64",
    "end_brightness": "float64",
    "mid_x": "float64",
    "mid_y": "float64",
    "gyro_residual_px": "float64",
    "llr_gyro": "float64",
    "llr_profile": "float64",
    "llr_continuity": "float64",
    "end_light_start": "float64",
    "end_light_end": "float64",
    "shape_deviation_px": "float64",
    "thick_saturated": "bool",
    "quality_ok": "bool",
    "source": "object",
    "reason": "object",
}
#: Version of the detection table's columns: 2 added ``source``, ``reason``,
#: ``end_light_start`` and ``end_light_end`` (and ``quality_ok`` became precision-first);
#: in the summary beside the table (``table_version``; the Parquet file stays the very file
#: ``DataFrame.to_parquet`` writes); 3 added ``gyro_residual_px``.
TABLE_VERSION = 3


def _cells(arrays: Sequence[np.ndarray], decimals: int) -> np.ndarray:
    """Per-streak arrays rounded (one rounding for the whole frame), as an object array of
    views of that one rounded array: no per-value Python floats, and the writer can hand
    them to Parquet as flat buffers (:func:`write_table`)."""
    out = np.empty(len(arrays), object)
    if not len(arrays):
        return out
    flat = np.round(np.concatenate(arrays), decimals)
    for i, cell in enumerate(split_at(flat, np.cumsum([len(a) for a in arrays])[:-1])):
        out[i] = cell
    return out


def frame_columns(
    frame: int, timestamp_ns: int, fs: FrameStreaks, ori: Orientation
) -> dict[str, Any]:
    """The rows of one frame as columns (arrays; ``orientation_source`` a list), ``fs``
    already oriented (end A = start); :func:`build_table` joins them."""
    N = len(fs)
    data = {
        "frame": np.full(N, frame, np.int64),
        "timestamp_ns": np.full(N, timestamp_ns, np.int64),
        "streak_id": np.arange(N, dtype=np.int64),
        "start_x": fs.end_a[:, 0],
        "start_y": fs.end_a[:, 1],
        "end_x": fs.end_b[:, 0],
        "end_y": fs.end_b[:, 1],
        "length_px": fs.length_px,
        "centerline": _cells(fs.points, 4),
        "profile": _cells(fs.profile, 6),
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
        "gyro_residual_px": fs.gyro_residual_px
        if len(fs.gyro_residual_px) == N
        else np.full(N, np.nan),
    }
    # Evidence for the recorded orientation (the LLRs were for the unswapped end A).
    signed = np.where(ori.swap[:, None], -ori.llr, ori.llr) if N else np.zeros((0, 3))
    data["llr_gyro"], data["llr_profile"], data["llr_continuity"] = signed.T
    if fs.evidence is not None:  # oriented with the streaks (FrameStreaks.reverse)
        data["end_light_start"], data["end_light_end"] = fs.evidence.end_light.T
        data["source"] = list(fs.evidence.source)
    if fs.quality is not None:  # computed by the frame's worker (the same definition)
        for name, col in zip(QUALITY_COLUMNS, fs.quality, strict=True):
            data[name] = list(col) if col.dtype == object else col
    return data


def frame_rows(frame: int, timestamp_ns: int, fs: FrameStreaks, ori: Orientation) -> pd.DataFrame:
    """The rows of one frame, ``fs`` already oriented (end A = start)."""
    return pd.DataFrame(frame_columns(frame, timestamp_ns, fs, ori))


def _join(parts: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """One DataFrame of the columns of ``parts`` (:func:`frame_columns`), as ``pd.concat``
    of their frames would give, without building a DataFrame per frame."""
    data = {
        c: [v for p in parts for v in p[c]]
        if isinstance(parts[0][c], list)
        else np.concatenate([p[c] for p in parts])
        for c in parts[0]
    }
    return pd.DataFrame(data)


def build_table(parts: Sequence[pd.DataFrame | Mapping[str, Any]]) -> pd.DataFrame:
    """Concatenate per-frame rows (:func:`frame_rows` or :func:`frame_columns`) into a
    validated table (empty table if none)."""
    parts = [p for p in parts if len(p["frame"])]
    if not parts:
        df = streaks.empty()
        for c, dt in EXTRA_COLUMNS.items():
            df[c] = pd.Series(dtype=dt)
        return df
    # Image evidence where every frame measured it (else the table has none: undetermined).
    if not all("source" in p for p in parts):
        parts = [
            p.drop(columns=["source", "end_light_start", "end_light_end"], errors="ignore")
            if isinstance(p, pd.DataFrame)
            else {
                k: v
                for k, v in p.items()
                if k not in ("source", "end_light_start", "end_light_end")
            }
            for p in parts
        ]
    # The quality columns where every frame's worker computed them, else here for all.
    have = all(isinstance(p, Mapping) and QUALITY_COLUMNS[0] in p for p in parts)
    if not have:
        drop = [c for c in QUALITY_COLUMNS if c != "source"]
        parts = [
            p.drop(columns=drop, errors="ignore")
            if isinstance(p, pd.DataFrame)
            else {k: v for k, v in p.items() if k not in drop}
            for p in parts
        ]
    if all(isinstance(p, Mapping) for p in parts):
        joined = _join([p for p in parts if isinstance(p, Mapping)])
    else:
        frames = [p if isinstance(p, pd.DataFrame) else pd.DataFrame(p) for p in parts]
        joined = pd.concat(frames, ignore_index=True)
    return streaks.validate(joined if have else add_quality(joined))


#: The list columns and their Arrow types (what pandas infers from lists of floats).
_LIST_TYPES = {"centerline": 2, "profile": 1}


def _list_array(cells: Sequence[np.ndarray], ndim: int) -> Any:
    """An Arrow ``list<double>`` (``ndim`` 1) or ``list<list<double>>`` (``ndim`` 2, rows of
    ``(n, 2)`` points) array from per-row float64 arrays, through flat buffers."""
    import pyarrow as pa

    sizes = np.fromiter(map(len, cells), np.int64, len(cells))
    offsets = np.zeros(sizes.size + 1, np.int32)
    np.cumsum(sizes, out=offsets[1:])
    flat = np.concatenate(cells) if len(cells) else np.zeros((0, 2) if ndim == 2 else 0)
    values = pa.array(flat.reshape(-1), pa.float64())
    if ndim == 2:
        pairs = np.arange(0, 2 * flat.shape[0] + 1, 2, dtype=np.int32)
        values = pa.ListArray.from_arrays(pa.array(pairs), values)
    return pa.ListArray.from_arrays(pa.array(offsets), values)


def _is_cells(column: pd.Series, ndim: int) -> bool:
    """Whether every cell is a float64 array of points (``ndim`` 2) or values (1) (tested
    attribute by attribute over all cells, each pass a ``map``: no Python loop per cell)."""
    cells = column.to_numpy(object)
    if not all(map(isinstance, cells, repeat(np.ndarray))):
        return False
    if set(map(attrgetter("dtype"), cells)) - {np.dtype(np.float64)}:
        return False
    if set(map(attrgetter("ndim"), cells)) - {ndim}:
        return False
    return ndim == 1 or not set(map(itemgetter(1), map(attrgetter("shape"), cells))) - {2}


def to_arrow(df: pd.DataFrame) -> Any:
    """``df`` (validated) as the Arrow table that ``DataFrame.to_parquet`` would write (the
    same schema and pandas metadata), with the list columns built from flat buffers when
    their cells are arrays (:func:`frame_rows`): converting lists of Python floats costs more
    than the rest of writing. Other tables go through ``pa.Table.from_pandas`` as a whole."""
    import pyarrow as pa

    lists = [c for c in _LIST_TYPES if c in df.columns]
    if not len(df) or not all(_is_cells(df[c], _LIST_TYPES[c]) for c in lists):
        return pa.Table.from_pandas(df, preserve_index=False)
    rest = pa.Table.from_pandas(df.drop(columns=lists), preserve_index=False)
    arrays = {c: _list_array(df[c].to_numpy(object), _LIST_TYPES[c]) for c in lists}
    fields = [
        pa.field(c, arrays[c].type) if c in arrays else rest.schema.field(c) for c in df.columns
    ]
    schema = pa.schema(fields)
    # pandas metadata as from_pandas writes it for these column types (from the empty head).
    meta = pa.Table.from_pandas(df.iloc[:0], schema=schema, preserve_index=False).schema.metadata
    columns = [arrays[c] if c in arrays else rest.column(c) for c in df.columns]
    return pa.Table.from_arrays(columns, schema=schema.with_metadata(meta))


def write_table(df: pd.DataFrame, path: str | Path) -> None:
    """Write the table as Parquet, atomically: the file :func:`blurtrack.io.streaks.write`
    writes (validated, the same options), through :func:`to_arrow`."""
    import pyarrow.parquet as pq

    table = to_arrow(streaks.validate(df))
    opts = streaks.parquet_options(table.column_names)
    # a file handle, not a path: pyarrow cannot encode non-UTF-8 file names
    atomic.write_atomic(path, lambda f: pq.write_table(table, f, **opts))


def read_table(path: str) -> pd.DataFrame:
    """Read and validate a streak table."""
    return streaks.read(path)
