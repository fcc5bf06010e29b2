"""The one output guard: no command writes into a recording, or over a result unless told to.

Every command with an output (``--out``, or an ``OUT`` argument) calls :func:`check_output`
before it writes anything. It refuses

* any output inside a session folder (docs/conventions.md) other than the derived names DESIGN
  reserves there (``streaks.parquet``, its ``streaks.summary.json``, ``derived/``): the
  recorded parts (``session.yaml``, ``truth.yaml``, ``cam0/``, ``imu0/``) and any other name
  (``SESSION/x``) — found by walking up from the output to the nearest folder that holds a
  ``session.yaml``, after resolving links, so ``S/cam0/../cam0/data`` and a link into a session
  are caught too;
* an output whose path, as written, passes through a session folder and then leaves it through
  a link (``SESSION/derived`` a link to another session's ``cam0/`` or anywhere else): derived
  files are written only into the session's own real folders;
* an output inside one of the command's input folders (``input_folders``: the dataset
  ``gamd train`` reads, the photos ``synth`` reads);
* a result folder that is a session folder itself (its files would mix with the recording);
* an output that is one of the command's own input files;
* an existing result (a file output that exists; a folder output holding a ``summary.json``)
  unless ``force`` (the command's ``--force``; commands that can continue take ``--resume``).

Refusals are :class:`OutputRefusedError`, one line naming the path and the reason.

:func:`output_lock` is the one lock of an output two runs could write at once (``calibrate
--out``, ``gamd train --out``; ``synth`` holds its dataset lock, :mod:`blurtrack.synth.store`):
a ``flock`` on a hidden ``.<name>.lock`` beside the output, taken without waiting, holding the
owner's pid; the second run is refused in one line naming that pid.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import fcntl
import hashlib
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

from blurtrack.errors import BlurTrackError
from blurtrack.io.atomic import NAME_MAX

#: The parts of a session folder a recorder wrote; nothing else may write there.
RECORDED = ("session.yaml", "truth.yaml", "cam0", "imu0")
#: Derived names DESIGN reserves inside a session folder.
RESERVED = ("streaks.parquet", "streaks.summary.json", "derived")


class OutputRefusedError(BlurTrackError):
    """An output path would overwrite recorded data, an input, or an existing result."""


def add_force_arg(parser: argparse.ArgumentParser) -> None:
    """The shared ``--force`` option (replace an existing result)."""
    parser.add_argument(
        "--force", action="store_true", help="replace an existing result at the output path"
    )


def _resolve(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # a link loop: judge the path as written
        return Path(os.path.abspath(path))


def _first_session(folders: Iterable[Path]) -> Path | None:
    """The first of ``folders`` that holds a ``session.yaml`` (unreadable ones passed over)."""
    for folder in folders:
        try:
            if (folder / "session.yaml").is_file():
                return folder
        except OSError:
            continue
    return None


def session_root(path: str | os.PathLike[str]) -> Path | None:
    """The nearest folder at or above ``path`` (resolved) that holds a ``session.yaml``."""
    p = _resolve(Path(path))
    return _first_session((p, *p.parents))


def _literal_session(out: Path) -> Path | None:
    """The nearest folder holding a ``session.yaml`` on the output's path *as written* (links
    not resolved), the folder itself excluded."""
    return _first_session(Path(os.path.abspath(out)).parents)


def _check_links(out: Path, name: str, what: str) -> None:
    """Refuse a path that enters a session and leaves it again through a link."""
    lit_root = _literal_session(out)
    if lit_root is None:
        return
    real_root = _resolve(lit_root)
    lit = Path(os.path.abspath(out))
    step = lit_root
    for part in lit.relative_to(lit_root).parts:
        step = step / part
        if step.is_symlink():
            target = _resolve(step)
            if not target.is_relative_to(real_root) or target == real_root:
                rel = os.fsdecode(step.relative_to(lit_root))
                raise OutputRefusedError(
                    f"{what} {name!r}: {rel!r} in the session {os.fsdecode(lit_root)!r} is a link "
                    f"to {os.fsdecode(target)!r}; derived files are written only into the "
                    "session's own folders"
                )


def check_output(
    path: str | os.PathLike[str],
    *,
    folder: bool = False,
    force: bool = False,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    what: str = "--out",
    siblings: Iterable[str] = (),
    input_folders: Iterable[str | os.PathLike[str] | None] = (),
) -> Path:
    """Refuse an output path that would damage a recording, an input or a result (see module).

    Args:
        folder: the output is a folder of results (else one file).
        force: an existing result may be replaced.
        inputs: the command's input files (a calibration, a streak table ...).
        what: how the command names the output in messages.
        siblings: names of further files the command writes beside the output: their
            lengths are checked too (a long name fails before any work, not half-way), an
            existing one is a result that only ``force`` replaces, and none may be an input.
        input_folders: folders the command reads (a dataset, a folder of photos): the output
            must not lie inside one (nor be one).

    Returns the path, unchanged.
    """
    out = Path(path)
    name = os.fsdecode(out)
    res = _resolve(out)
    siblings = tuple(siblings)
    _check_links(out, name, what)
    root = session_root(out)
    if root is not None:
        rel = res.relative_to(root).parts
        if not rel and folder:
            raise OutputRefusedError(
                f"{what} {name!r} is a session folder; results go in a folder of their own"
            )
        if rel and rel[0] in RECORDED:
            raise OutputRefusedError(
                f"{what} {name!r} is inside the recorded part {rel[0]!r} of the session "
                f"{os.fsdecode(root)!r}; recorded data is never overwritten"
            )
        if not rel and not folder:
            raise OutputRefusedError(f"{what} {name!r} is a session folder, not a file")
        if rel[0] not in RESERVED:
            raise OutputRefusedError(
                f"{what} {name!r} is inside the session folder {os.fsdecode(root)!r}; a session "
                f"holds only its recording and {', '.join(RESERVED)}: write results elsewhere"
            )
    for inp in input_folders:
        if inp is None:
            continue
        top = _resolve(Path(inp))
        if res == top or res.is_relative_to(top):
            raise OutputRefusedError(
                f"{what} {name!r} is inside {os.fsdecode(inp)!r}, an input folder of this command"
            )
    for part in (*out.parts, *siblings):
        if len(os.fsencode(part)) > NAME_MAX:
            raise OutputRefusedError(
                f"{what} {name!r}: the name {part[:40]!r}... is longer than {NAME_MAX} bytes"
            )
    anc = res
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    probe = anc if anc.is_dir() else anc.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputRefusedError(
            f"{what} {name!r}: the folder {os.fsdecode(probe)!r} is not writable"
        )
    ins = {_resolve(Path(inp)) for inp in inputs if inp is not None}
    if res in ins:
        raise OutputRefusedError(f"{what} {name!r} is also an input of this command")
    for sib in siblings:
        beside = _resolve(res.parent / sib)
        if beside in ins:
            raise OutputRefusedError(
                f"{what} {name!r}: {sib!r}, written beside it, is an input of this command"
            )
        if not force and beside.exists():
            raise OutputRefusedError(
                f"{what} {name!r}: {sib!r} beside it exists (an earlier result); "
                "--force replaces it"
            )
    if not force:
        if folder and (res / "summary.json").exists():
            raise OutputRefusedError(
                f"{what} {name!r} already holds a result (summary.json); --force replaces it"
            )
        if not folder and res.exists():
            raise OutputRefusedError(f"{what} {name!r} exists; --force replaces it")
    if res.exists() and (res.is_dir() != folder):
        kind = "a folder" if res.is_dir() else "a file"
        raise OutputRefusedError(f"{what} {name!r} is {kind}")
    return out


def check_new_folder(path: str | os.PathLike[str], what: str = "output folder") -> Path:
    """An output folder that must not exist or be empty (a new session, a new dataset)."""
    out = check_output(path, folder=True, force=True, what=what)
    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise OutputRefusedError(f"{what} {os.fsdecode(out)!r} exists and is not empty")
    except OSError as exc:
        raise OutputRefusedError(f"{what} {os.fsdecode(out)!r}: {exc.strerror or exc}") from None
    return out


def _lock_name(path: Path) -> Path:
    name = f".{path.name}.lock"
    if len(os.fsencode(name)) > NAME_MAX:  # a long output name: its hash names the lock
        name = f".{hashlib.sha256(os.fsencode(path.name)).hexdigest()[:32]}.lock"
    return path.with_name(name)


@contextlib.contextmanager
def output_lock(path: str | os.PathLike[str], what: str = "--out") -> Iterator[Path]:
    """Hold the lock of output ``path`` (file or folder) while the block runs.

    A ``flock`` on ``.<name>.lock`` beside the output, taken without waiting; the file holds
    the owner's pid. A second run is refused with :class:`OutputRefusedError` (``X is being
    written by another run (pid N)``). The kernel drops the lock when its process dies, so a
    killed run never blocks the next one; the lock file is removed when the block ends.
    """
    out = Path(path)
    lock = _lock_name(Path(os.path.abspath(out)))
    name = os.fsdecode(out)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputRefusedError(f"{what} {name!r}: {exc.strerror or exc}") from None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise OutputRefusedError(
                f"{what} {name!r}: cannot create its lock file: {exc.strerror or exc}"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            owner = _read_pid(fd)
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                who = f" (pid {owner})" if owner else ""
                raise OutputRefusedError(
                    f"{name} is being written by another run{who}; wait for it to end or "
                    f"choose another {what}"
                ) from None
            raise OutputRefusedError(f"{what} {name!r}: cannot lock: {exc.strerror}") from None
        try:  # the file we locked must still be the one at the lock's name
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)  # the previous owner removed it between our open and our lock
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
    except OSError:
        pass  # a full disk: the lock holds without the pid
    try:
        yield lock
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        return int(text) if text.isdigit() else None
    except OSError:
        return None
