"""Reader for recorded hand-shake gyro traces (GyroDeblurNet's ``gyro_train.txt`` layout).

The file holds one sample per line, whitespace (tab) separated: ``timestamp_ns wx wy wz`` with
angular velocity in rad/s on the recording phone's own clock and axes. Lines starting with
``#`` and blank lines are ignored. The trace is returned as a :class:`~blurtrack.gyro.GyroTrace`
(seconds, shifted so that the first sample is at 0 s to keep float64 time resolution at
nanoseconds); its gaps (the file has one dropout of about 26 ms) are left to the trace's
coverage checks, so a caller that asks for an interval inside a gap gets a one-line error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from blurtrack.errors import ImportFormatError
from blurtrack.gyro import GyroTrace

#: Largest shake file read (bytes): a few hours of 1 kHz samples.
MAX_SHAKE_BYTES = 512 * 1024**2


def read_shake(path: str | Path, max_gap_s: float | None = None) -> tuple[GyroTrace, int]:
    """Load a shake file.

    Returns:
        ``(trace, t0_ns)``: the trace with times in seconds relative to the first sample, and
        that first sample's timestamp in nanoseconds (to map segment times back to the file).
    """
    p = Path(path)
    if not p.is_file():
        raise ImportFormatError(f"shake file not found: {p}")
    if p.stat().st_size > MAX_SHAKE_BYTES:
        raise ImportFormatError(f"shake file {p} is larger than {MAX_SHAKE_BYTES} bytes")
    try:
        df = pd.read_csv(p, sep=r"\s+", header=None, comment="#", dtype=str)
    except pd.errors.EmptyDataError:
        raise ImportFormatError(f"shake file {p} is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise ImportFormatError(f"shake file {p} is malformed: "
                                f"{str(exc).splitlines()[0]}") from None
    if df.shape[1] != 4:
        raise ImportFormatError(f"shake file {p} has {df.shape[1]} columns, expected 4 "
                                f"(timestamp_ns wx wy wz)")
    t_ns = pd.to_numeric(df[0], errors="coerce")
    omega = df[[1, 2, 3]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = t_ns.isna().to_numpy() | ~np.all(np.isfinite(omega), axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ImportFormatError(f"shake file {p}: data row {k + 1} is not four finite numbers: "
                                f"{' '.join(df.iloc[k].astype(str))!r}")
    t_int = np.asarray([int(v) for v in df[0]], dtype=np.int64)
    d = np.diff(t_int)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0])
        raise ImportFormatError(f"shake file {p}: timestamps not strictly increasing at data "
                                f"row {k + 2}")
    if t_int.size < 2:
        raise ImportFormatError(f"shake file {p} has fewer than 2 samples")
    t0 = int(t_int[0])
    return GyroTrace((t_int - t0) * 1e-9, omega, max_gap_s), t0
