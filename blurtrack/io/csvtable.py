"""The CSV tables of a session folder, read defensively (sizes, syntax, finite numbers, int64
nanoseconds, strictly increasing stamps); used by :mod:`blurtrack.io.session`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from blurtrack.errors import SessionError

#: Largest CSV read (bytes); guards against allocating for a hostile file.
MAX_CSV_BYTES = 2 * 1024**3


def read_csv_table(path: Path, what: str, ncols: tuple[int, ...]) -> pd.DataFrame:
    """A session CSV (``cam0/data.csv``, ``imu0/data.csv``) as strings, after its ``#`` header;
    size, syntax and column count checked (one-line :class:`SessionError` otherwise)."""
    if not path.is_file():
        raise SessionError(f"{what} missing: {path}")
    if path.stat().st_size > MAX_CSV_BYTES:
        raise SessionError(f"{what} {path} is larger than {MAX_CSV_BYTES} bytes")
    try:
        df = pd.read_csv(
            path,
            header=None,
            comment=None,
            dtype=str,
            skiprows=1,
            skipinitialspace=True,
            keep_default_na=False,
            on_bad_lines="error",
        )
    except pd.errors.EmptyDataError:
        df = pd.DataFrame(columns=range(ncols[0]))
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise SessionError(f"{what} {path} is malformed: {str(exc).splitlines()[0]}") from None
    with path.open("r", encoding="utf-8", errors="replace") as f:
        header = f.readline()
    if not header.startswith("#"):
        raise SessionError(f"{what} {path}: the first line must be a '#' header")
    if df.shape[1] not in ncols:
        raise SessionError(
            f"{what} {path} has {df.shape[1]} columns, expected {' or '.join(map(str, ncols))}"
        )
    return df


def numeric_column(df: pd.DataFrame, col: int, path: Path, integer: bool) -> np.ndarray:
    """Column ``col`` as finite floats, or (``integer``) whole int64 nanoseconds."""
    s = pd.to_numeric(df[col], errors="coerce")
    bad = s.isna() | ~np.isfinite(s.to_numpy(float, na_value=np.nan))
    if bad.any():
        line = int(np.flatnonzero(bad.to_numpy())[0]) + 2
        raise SessionError(
            f"{path}: line {line}, column {col + 1}: {df[col].iloc[line - 2]!r} "
            f"is not a finite number"
        )
    if integer:  # nanosecond stamps and exposures: whole numbers that fit int64
        text = df[col].astype(str).str.strip()
        whole = text.str.fullmatch(r"[+-]?\d{1,19}").to_numpy(bool)
        values = [int(v) if ok else 0 for v, ok in zip(text, whole, strict=True)]
        fits = whole & np.array([-(2**63) <= v < 2**63 for v in values], dtype=bool)
        if not fits.all():
            line = int(np.flatnonzero(~fits)[0]) + 2
            raise SessionError(
                f"{path}: line {line}, column {col + 1}: {df[col].iloc[line - 2]!r} "
                f"is not a whole number of nanoseconds within int64"
            )
        return np.asarray(values, dtype=np.int64)
    return s.to_numpy(dtype=float)


def check_strictly_increasing(t: np.ndarray, path: Path) -> None:
    """Refuse duplicate or unsorted timestamps, naming the line."""
    d = np.diff(t)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0])
        kind = "duplicate" if d[k] == 0 else "unsorted"
        raise SessionError(f"{path}: {kind} timestamp {t[k + 1]} at line {k + 3}")
