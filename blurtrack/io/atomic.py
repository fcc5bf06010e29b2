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
    short = exc.errno is None and "written" in str(exc)  # numpy: "N requested and M written"
    if exc.errno in (errno_mod.ENOSPC, errno_mod.EDQUOT) or (
        exc.errno is None and (short or _disk_full(Path(path).parent))
    ):
        reason = "no space left on the device"  # numpy reports short writes without errno
    elif exc.errno == errno_mod.EFBIG:
        reason = "no space left for it: the file size limit (ulimit -f) was reached"
    elif exc.errno == errno_mod.EROFS:
        reason = "the file system is read-only"
    err = OutputError(f"cannot {what} {os.fsdecode(path)!r}: {reason}")
    err.errno = exc.errno
    return err


#: ``errno`` values only a write meets: a full disk, a quota or file size limit, a read-only
#: file system.
DISK_ERRNOS = frozenset({errno_mod.ENOSPC, errno_mod.EDQUOT, errno_mod.EFBIG, errno_mod.EROFS})


def _disk_full(folder: Path) -> bool:
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < (1 << 16)


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

    For writers that want a path (``torch.save``, ``shutil.copy2``); prefer
    :func:`write_atomic` with a file handle for libraries that cannot encode non-UTF-8 names
    (pyarrow, OpenCV). The
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
        # judged before the cleanup frees the space a full disk ran out of
        err = output_error(target, exc) if isinstance(exc, OSError) else None
        with suppress(OSError):
            tmp.unlink(missing_ok=True)
        if err is not None and not isinstance(exc, OutputError):
            raise err from None
        raise
    _fsync_dir(target.parent)


@contextmanager
def atomic_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a hidden temporary folder beside ``path``; on a clean exit rename it to ``path``.

    For outputs that are whole folders (a converted or imported session): a reader finds
    either no folder (or the empty one it named) or the complete one, never half a session
    claiming to be whole. ``path`` must not exist or be an empty folder. On any exception the
    temporary folder is removed; ``OSError`` becomes :class:`OutputError`.
    """
    import shutil

    target = Path(path)
    _make_parent(target)
    tmp = target.with_name(temp_name(target.name))
    try:
        tmp.mkdir(0o777)
    except OSError as exc:
        raise output_error(target, exc, "create the folder") from None
    try:
        yield tmp
        os.replace(tmp, target)  # an empty target folder is replaced atomically too
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise output_error(target, exc) from None
        raise
    _fsync_dir(target.parent)


@contextmanager
def atomic_new(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a path that does not exist yet, inside a hidden temporary folder beside ``path``;
    on a clean exit rename what the body made there (a file or a folder) to ``path``.

    For writers that insist on creating their output themselves (``rosbags`` refuses an
    existing file or folder). ``path`` must not exist (or, for a folder, be empty). On any
    exception the temporary folder is removed; ``OSError`` becomes :class:`OutputError`.
    """
    import shutil

    target = Path(path)
    _make_parent(target)
    tmp = target.with_name(temp_name(target.name, "new"))
    try:
        tmp.mkdir(0o777)
    except OSError as exc:
        raise output_error(target, exc, "create the folder") from None
    try:
        made = tmp / target.name
        yield made
        os.replace(made, target)
    except BaseException as exc:
        err = output_error(target, exc) if isinstance(exc, OSError) else None
        shutil.rmtree(tmp, ignore_errors=True)
        if err is not None and not isinstance(exc, OutputError):
            raise err from None
        raise
    with suppress(OSError):
        tmp.rmdir()
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


def _finite_or_none(obj: Any) -> Any:
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # numpy scalars, arrays
        obj = obj.tolist()
    if isinstance(obj, float):
        return obj if obj == obj and obj not in (float("inf"), float("-inf")) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    return obj


def write_json_atomic(path: str | os.PathLike[str], obj: Any, **dumps: Any) -> Path:
    """``obj`` as strict JSON (NaN and infinities become ``null``: always valid JSON)."""
    import json

    dumps.setdefault("indent", 2)
    text = json.dumps(_finite_or_none(obj), allow_nan=False, **dumps) + "\n"
    return write_text_atomic(path, text)
