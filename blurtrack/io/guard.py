"""The one output guard: no command writes into a recording, or over a result unless told to.

Every command with an output (``--out``, or an ``OUT`` argument) calls :func:`check_output`
before it writes anything. It refuses

* any output inside the *recorded* parts of a session (docs/conventions.md): ``session.yaml``,
  ``truth.yaml``, ``cam0/``, ``imu0/`` — found by walking up from the output to the nearest
  folder that holds a ``session.yaml``, after resolving links, so ``S/cam0/../cam0/data`` and a
  link into a session are caught too. The derived names DESIGN reserves inside a session
  (``streaks.parquet``, its ``streaks.summary.json``, ``derived/``) stay allowed;
* a result folder that is a session folder itself (its files would mix with the recording);
* an output that is one of the command's own input files;
* an existing result (a file output that exists; a folder output holding a ``summary.json``)
  unless ``force`` (the command's ``--force``; commands that can continue take ``--resume``).

Refusals are :class:`OutputRefusedError`, one line naming the path and the reason.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterable
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


def session_root(path: str | os.PathLike[str]) -> Path | None:
    """The nearest folder at or above ``path`` (resolved) that holds a ``session.yaml``."""
    p = _resolve(Path(path))
    for folder in (p, *p.parents):
        try:
            if (folder / "session.yaml").is_file():
                return folder
        except OSError:
            continue
    return None


def check_output(
    path: str | os.PathLike[str],
    *,
    folder: bool = False,
    force: bool = False,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    what: str = "--out",
    siblings: Iterable[str] = (),
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

    Returns the path, unchanged.
    """
    out = Path(path)
    name = os.fsdecode(out)
    res = _resolve(out)
    siblings = tuple(siblings)
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
