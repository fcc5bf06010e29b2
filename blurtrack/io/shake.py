"""Real hand-shake gyroscope traces (GyroDeblurNet's ``gyro_train.txt``) as a motion source.

The file has tab- (or space-) separated rows ``timestamp_ns wx wy wz`` (rad/s). The trace is
used as camera-frame angular velocity: which phone axis was which is irrelevant for a library
of shake, but the axes are kept as recorded. This is the project's one reader of such files:
blur synthesis uses it directly and the simulated rig (``rigs.sim.shake``) wraps its result.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.geometry.gyro import GyroTrace

#: Refuse files larger than this (bytes) before reading them.
MAX_SHAKE_BYTES = 512 * 1024**2


def read_shake_trace(path: str | Path) -> GyroTrace:
    """Read a shake file into a :class:`GyroTrace` (seconds from the first sample).

    Dropouts stay as gaps; :meth:`GyroTrace.check_coverage` refuses intervals that cross one.
    """
    p = Path(path)
    if not p.is_file():
        raise ImportFormatError(f"shake trace not found: {p}")
    if p.stat().st_size > MAX_SHAKE_BYTES:
        raise ImportFormatError(f"shake trace {p} is larger than {MAX_SHAKE_BYTES} bytes")
    t_ns: list[int] = []
    rows: list[tuple[float, float, float]] = []
    with p.open("r", encoding="utf-8", errors="strict") as f:
        try:
            for n, line in enumerate(f, start=1):
                parts = line.split()
                if not parts or parts[0].startswith("#"):
                    continue
                if len(parts) != 4:
                    raise ImportFormatError(
                        f"{p}: line {n} has {len(parts)} fields, expected 4 (timestamp_ns wx wy wz)"
                    )
                try:
                    t_ns.append(int(parts[0]))
                    w = (float(parts[1]), float(parts[2]), float(parts[3]))
                except ValueError:
                    raise ImportFormatError(
                        f"{p}: line {n} is not numeric: {line.strip()[:60]!r}"
                    ) from None
                if not all(np.isfinite(w)):
                    raise ImportFormatError(f"{p}: line {n} holds a non-finite rate (NaN or inf)")
                rows.append(w)
        except UnicodeDecodeError as exc:
            raise ImportFormatError(f"{p}: not UTF-8 text ({exc.reason})") from None
    if len(rows) < 2:
        raise ImportFormatError(f"{p}: fewer than 2 samples")
    t = np.asarray(t_ns, dtype=np.int64)
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ImportFormatError(f"{p}: timestamps not increasing at line {k + 2}")
    return GyroTrace((t - t[0]) * 1e-9, np.asarray(rows, dtype=float))
