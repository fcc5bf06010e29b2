"""The one atomic file writer: temporary file in the target's folder, fsync, rename.

Every file the project writes as a whole (calibrations, summaries, tables, frames, checkpoints)
goes through :func:`atomic_path` (or its shorthands :func:`write_bytes_atomic` and
:func:`write_text_atomic`), so that

* a reader sees either the old file or the complete new one, never a torn one;
* the new file's permissions come from the umask (``0o666 & ~umask``, like ``open()``), not
  ``mkstemp``'s private ``0o600``: colleagues can read a calibration on a shared disk;
* the temporary file is removed on every error, ``ENOSPC``, ``EROFS``, ``EACCES`` and
  ``KeyboardInterrupt`` included: no ``.tmp`` debris;
* the temporary name is never longer than 255 bytes, whatever the target's name length;
* an operating-system error becomes one :class:`OutputError` line naming the path and the
  reason (it is also an :class:`OSError`, so callers that handle ``OSError`` keep working).

Temporary names look like ``.<name>.<tag>.<random>.tmp`` (``<name>`` shortened when needed):
hidden, recognisable, and globbable per tag by code that cleans up after a killed process.
"""

from __future__ import annotations

import errno as errno_mod
import os
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any

from blurtrack.errors import BlurTrackError

#: Longest file name most file systems accept (bytes).
NAME_MAX = 255
#: Suffix of every temporary file this module creates.
TMP_SUFFIX = ".tmp"


class OutputError(BlurTrackError, OSError):
    """A file could not be written (full disk, read-only folder, permissions, name too long)."""


def output_error(path: str | os.PathLike[str], exc: OSError, what: str = "write") -> OutputError:
    """One-line :class:`OutputError` for an ``OSError`` met while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.errno == errno_mod.ENOSPC:
        reason = "no space left on the device"
    err = OutputError(f"cannot {what} {os.fsdecode(path)!r}: {reason}")
    err.errno = exc.errno
    return err


def temp_name(name: str, tag: str = "") -> str:
    """The hidden temporary name for target file ``name`` (at most :data:`NAME_MAX` bytes)."""
    token = secrets.token_hex(4)
    middle = f".{tag}.{token}" if tag else f".{token}"
    budget = NAME_MAX - len(os.fsencode(f".{middle}{TMP_SUFFIX}"))
    stem_text = name  # cut whole characters (an escaped undecodable byte is one character)
    while stem_text and len(os.fsencode(stem_text)) > budget:
        stem_text = stem_text[: -max(1, (len(os.fsencode(stem_text)) - budget) // 4)]
    return f".{stem_text}{middle}{TMP_SUFFIX}"


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems do not sync directories; the rename itself is atomic
    finally:
        os.close(fd)


def _make_parent(path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(path.parent, exc, "create the folder") from None


@contextmanager
def atomic_path(path: str | os.PathLike[str], tag: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit, fsync and rename it to ``path``.

    For writers that want a path (``DataFrame.to_parquet``, ``torch.save``, ``np.save``). The
    temporary file already exists (empty, umask permissions) when the body runs. On any
    exception it is removed; ``OSError`` becomes :class:`OutputError`.
    """
    target = Path(path)
    _make_parent(target)
    tmp = target.with_name(temp_name(target.name, tag))
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.close(fd)
    except OSError as exc:
        raise output_error(target, exc) from None
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    except BaseException as exc:
        with suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise output_error(target, exc) from None
        raise
    _fsync_dir(target.parent)


def write_atomic(
    path: str | os.PathLike[str], write: Callable[[IO[bytes]], Any], tag: str = ""
) -> Path:
    """Write ``path`` atomically by calling ``write(binary_file)``; returns the path."""
    with atomic_path(path, tag) as tmp, open(tmp, "wb") as f:
        write(f)
        f.flush()
    return Path(path)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, tag: str = "") -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring)."""
    return write_atomic(path, lambda f: f.write(data), tag)


def write_text_atomic(
    path: str | os.PathLike[str], text: str, encoding: str = "utf-8", tag: str = ""
) -> Path:
    """Write ``text`` to ``path`` atomically (see the module docstring)."""
    return write_bytes_atomic(path, text.encode(encoding), tag)
