"""Number tables of unknown layout (a lab's frame-times file or gyro CSV): rows of numbers
split on commas, semicolons, tabs or spaces, an optional header, and the time unit, time column
and gyro unit decided from the data where they are not given (:mod:`blurtrack.io.importers.frames`
is their importer; its docstring states the rules)."""

from __future__ import annotations

import re
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.io.importers.common import text_lines

#: Nanoseconds per time unit.
TIME_UNITS = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}
#: Frame interval range (s) the detected unit must put the median frame interval in.
FRAME_INTERVAL_S = (2e-3, 2.0)
#: Gyro sample interval range (s) the detected unit must put the median gyro interval in.
GYRO_INTERVAL_S = (1e-4, 0.1)
GYRO_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
#: |ω| above this (35 rad/s = 2000 deg/s, the largest common MEMS full scale) cannot be rad/s.
MAX_RADPS = 35.0
SPLIT = re.compile(r"[,;\t ]+")
TIME_NAMES = ("t", "time", "timestamp", "ts", "stamp", "t_s", "t_ns", "time_s", "timestamp_ns")
AXIS_NAMES = {
    "wx": ("wx", "gx", "w_x", "gyro_x", "gyrox", "omega_x", "x"),
    "wy": ("wy", "gy", "w_y", "gyro_y", "gyroy", "omega_y", "y"),
    "wz": ("wz", "gz", "w_z", "gyro_z", "gyroz", "omega_z", "z"),
}


def decimal_of(text: str, where: str) -> Decimal:
    try:
        d = Decimal(text.strip())
    except InvalidOperation:
        raise ImportFormatError(f"{where}: {text.strip()!r} is not a number") from None
    if not d.is_finite():
        raise ImportFormatError(f"{where}: {text.strip()!r} is not finite")
    return d


def is_number(text: str) -> bool:
    try:
        return Decimal(text.strip()).is_finite()
    except InvalidOperation:
        return False


def numeric_table(path: Path, min_fields: int) -> bool:
    """Whether the first data line of ``path`` (after comments and one header line) is
    ``min_fields`` or more numbers: a table, not a free-form log."""
    try:
        with path.open(encoding="utf-8", errors="replace") as f:
            seen = 0
            for line in f:
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                tokens = [t for t in SPLIT.split(s) if t]
                if all(is_number(t) for t in tokens):
                    return len(tokens) >= min_fields
                seen += 1
                if seen > 1:
                    return False
    except OSError:
        return False
    return False


def table_rows(path: Path) -> tuple[list[str] | None, list[list[str]], int]:
    """(header tokens or None, rows of tokens, line number of the first row) of a text table;
    ``#`` comment lines and blank lines are skipped."""
    header: list[str] | None = None
    rows: list[list[str]] = []
    first = 0
    for n, line in enumerate(text_lines(path), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tokens = [t for t in SPLIT.split(s) if t]
        if not rows and header is None and not any(is_number(t) for t in tokens):
            header = [t.strip().lower() for t in tokens]
            continue
        if not rows:
            first = n
        rows.append(tokens)
    return header, rows, first


def unit_of(values: list[Decimal], given: str | None, span: tuple[float, float], what: str) -> str:
    """The time unit of ``values`` (raw): the one that puts their median positive step in
    ``span`` seconds; ``given`` (``--time-unit``) must do so too (a wrong unit makes 30 fps
    30 000 fps or one frame in 33 s: refused, not imported)."""
    if given is not None and given not in TIME_UNITS:
        raise ImportFormatError(f"time unit must be one of {list(TIME_UNITS)}, got {given!r}")
    arr = np.array([float(v) for v in values])
    d = np.abs(np.diff(arr))
    d = d[d > 0]
    if d.size == 0:
        raise ImportFormatError(f"{what}: fewer than 2 distinct times")
    step = float(np.median(d))
    fits = [u for u, ns in TIME_UNITS.items() if span[0] <= step * ns * 1e-9 < span[1]]
    if given is not None:
        if given not in fits:
            raise ImportFormatError(
                f"{what}: with --time-unit {given} the median step is "
                f"{step * TIME_UNITS[given] * 1e-9:g} s, outside [{span[0]:g}, {span[1]:g}) s"
            )
        return given
    if len(fits) != 1:
        raise ImportFormatError(
            f"{what}: a median step of {step:g} fits no time unit with a step in "
            f"[{span[0]:g}, {span[1]:g}) s; give --time-unit"
        )
    return fits[0]


def to_ns(v: Decimal, unit: str) -> int:
    return int((v * TIME_UNITS[unit]).to_integral_value())


def gyro_columns(
    header: list[str] | None, rows: list[list[str]], given: str | None, path: Path
) -> tuple[dict[str, int], str]:
    """Column index of ``t``, ``wx``, ``wy``, ``wz`` and how they were found."""
    width = len(rows[0])
    if given is not None:
        names = [c.strip().lower() for c in given.split(",")]
        if sorted(n for n in names if n != "-") != ["t", "wx", "wy", "wz"] or len(names) > width:
            raise ImportFormatError(
                f"--gyro-columns must name t, wx, wy, wz once each ('-' skips a column) "
                f"within the file's {width} columns, got {given!r}"
            )
        return {n: i for i, n in enumerate(names) if n != "-"}, "--gyro-columns"
    if header is not None and len(header) == width:
        cols: dict[str, int] = {}
        for i, h in enumerate(header):
            key = h.split("[")[0].strip().strip("#").strip()
            if "t" not in cols and (key in TIME_NAMES or "time" in key or "stamp" in key):
                cols["t"] = i
            for axis, aliases in AXIS_NAMES.items():
                if axis not in cols and key in aliases:
                    cols[axis] = i
        if len(cols) == 4:
            return cols, f"the header ({', '.join(header)})"
    if width not in (4, 7):
        raise ImportFormatError(
            f"{path}: {width} columns and no header naming them; give --gyro-columns"
        )
    data = np.array([[float(t) for t in r] for r in rows[: min(len(rows), 2000)]])
    rising = [
        i for i in range(width) if np.all(np.diff(data[:, i]) >= 0) and np.ptp(data[:, i]) > 0
    ]
    if len(rising) != 1:
        raise ImportFormatError(
            f"{path}: cannot tell the time column ({len(rising)} columns increase); "
            "give --gyro-columns"
        )
    t = rising[0]
    rest = [i for i in range(width) if i != t][:3]
    if t not in (0, width - 1):
        raise ImportFormatError(
            f"{path}: the increasing column {t + 1} is neither first nor last; give --gyro-columns"
        )
    return dict(zip(("t", "wx", "wy", "wz"), [t, *rest], strict=True)), (
        f"time = the increasing column {t + 1}, gyro x, y, z = columns "
        f"{', '.join(str(i + 1) for i in rest)}"
    )


def read_gyro(
    path: Path, columns: str | None, time_unit: str | None, gyro_unit: str | None
) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    """``(t_ns (N,), omega_radps (N, 3), assumptions)`` of a gyro CSV, sorted, repeats dropped."""
    header, rows, first = table_rows(path)
    if len(rows) < 2:
        raise ImportFormatError(f"{path}: fewer than 2 gyro rows")
    width = len(rows[0])
    for n, r in enumerate(rows, start=first):
        if len(r) != width:
            raise ImportFormatError(f"{path}: row {n - first + 1} has {len(r)} fields, not {width}")
    cols, how = gyro_columns(header, rows, columns, path)
    raw_t = [decimal_of(r[cols["t"]], f"{path} row {i + 1}") for i, r in enumerate(rows)]
    try:
        w = np.array([[float(r[cols[a]]) for a in ("wx", "wy", "wz")] for r in rows])
    except ValueError:
        raise ImportFormatError(f"{path}: a gyro value is not a number") from None
    if not np.all(np.isfinite(w)):
        raise ImportFormatError(f"{path}: non-finite gyro value")
    unit = unit_of(raw_t, time_unit, GYRO_INTERVAL_S, str(path))
    t_ns = np.array([to_ns(v, unit) for v in raw_t], np.int64)
    peak = float(np.abs(w).max())
    if gyro_unit is None:
        g_unit = "deg/s" if peak > MAX_RADPS else "rad/s"
        g_how = (
            f"deg/s (peak {peak:.1f} exceeds {MAX_RADPS} rad/s)"
            if g_unit == "deg/s"
            else f"rad/s (peak {peak:.3g}; give --gyro-unit deg/s if it is not)"
        )
    elif gyro_unit in GYRO_UNITS:
        g_unit, g_how = gyro_unit, f"{gyro_unit} (from --gyro-unit)"
    else:
        raise ImportFormatError(f"--gyro-unit must be one of {list(GYRO_UNITS)}, got {gyro_unit!r}")
    omega = w * GYRO_UNITS[g_unit]
    if float(np.abs(omega).max()) > MAX_RADPS:
        raise ImportFormatError(
            f"{path}: gyro peak {float(np.abs(omega).max()):.1f} rad/s exceeds {MAX_RADPS} rad/s"
        )
    order = np.argsort(t_ns, kind="stable")
    keep = order[np.r_[True, np.diff(t_ns[order]) > 0]]
    assumptions = {
        "gyro_columns": how,
        "gyro_time_unit": f"{unit}" + (" (from --time-unit)" if time_unit else " (detected)"),
        "gyro_unit": g_how,
    }
    return t_ns[keep], omega[keep], assumptions
