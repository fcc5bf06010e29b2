"""The ``blurtrack`` command line.

Each package registers its own commands: ``blurtrack/cli/<name>.py`` (simulate, import,
validate, detect, report, predict, synth, demo), ``calib/cli.py`` (calibrate) and ``rigs/cli.py``
(record, recover); ``gamd/cli.py`` is the separate ``gamd`` program. Each module exposes
``register(subparsers) -> None``; each registered parser
sets ``func`` to a callable ``(argparse.Namespace) -> int``. :data:`COMMANDS` declares every
command (name, module, one-line help), so ``blurtrack CMD ...`` imports only CMD's module and
lists the others from their declarations (``blurtrack --help`` imports none); the modules import
their heavy dependencies inside their command functions.

This is the only layer that prints summaries and chooses exit codes: library code raises
:class:`blurtrack.errors.BlurTrackError` subclasses, which become one line on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from collections.abc import Sequence
from typing import Any, TypeVar

from blurtrack.errors import BlurTrackError

#: Every subcommand in help order: its name, the module that registers it and its one-line
#: help (the module's own, checked by the tests). A module missing from an installation (an
#: optional package) contributes no commands, not an error.
COMMANDS: tuple[tuple[str, str, str], ...] = (
    (
        "simulate",
        "blurtrack.cli.simulate",
        "render a simulated laser-grid session (with truth.yaml)",
    ),
    ("import", "blurtrack.cli.importers", "convert a third-party recording into a session folder"),
    ("validate", "blurtrack.cli.validate", "check a session folder thoroughly"),
    (
        "detect",
        "blurtrack.cli.detect",
        "detect laser-dot streaks and write the streak table (Parquet)",
    ),
    ("calibrate", "calib.cli", "fit the gyro blur model to a session's streaks"),
    ("report", "blurtrack.cli.report", "endpoint-error report of a calibration"),
    (
        "predict",
        "blurtrack.cli.predict",
        "per-frame blur heat maps and trajectories of a recording",
    ),
    (
        "synth",
        "blurtrack.cli.synth",
        "synthesise calibrated training triplets (sharp, blur, heat maps)",
    ),
    ("synth-merge", "blurtrack.cli.synth", "combine dataset shards into one manifest"),
    (
        "record",
        "rigs.cli",
        "record an IMU and a camera into a crash-safe log and a session folder",
    ),
    ("recover", "rigs.cli", "salvage a recorder log cut short (crash, SIGKILL, full disk)"),
    ("export", "blurtrack.cli.export", "write a session in another tool's format (ROS bag)"),
    ("demo", "blurtrack.cli.demo", "run the whole pipeline on the simulated rig"),
)

#: Modules that contribute subcommands, in help order.
COMMAND_MODULES: tuple[str, ...] = tuple(dict.fromkeys(m for _, m, _ in COMMANDS))


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to an option's help unless it already names its default.

    Options without a meaningful default (``None``, flags that default to ``False``) are left
    as they are; their help text says what happens when they are not given.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if has_shown_default(action) and "default" not in text.lower():
            text = f"{text} (default: %(default)s)" if text else "default: %(default)s"
        return text


def has_shown_default(action: argparse.Action) -> bool:
    """Whether an option has a default worth showing (not None, empty, a flag or SUPPRESS)."""
    d = action.default
    return (
        bool(action.option_strings)
        and action.help is not argparse.SUPPRESS
        and d is not None
        and d is not argparse.SUPPRESS
        and not isinstance(d, bool)
        and d != ""
    )


_ActionT = TypeVar("_ActionT", bound=argparse.Action)


class CommandParser(argparse.ArgumentParser):
    """ArgumentParser whose help shows defaults; subcommand parsers inherit it."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def _add_action(self, action: _ActionT) -> _ActionT:
        # an option without help text is not listed by argparse: give it its default
        if action.help is None and has_shown_default(action):
            action.help = "default: %(default)s"
        return super()._add_action(action)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``blurtrack`` parser: every command in full (``command=None``), or only
    ``command``'s module imported and registered and the other commands listed from
    :data:`COMMANDS` (same top-level help, nothing of theirs imported)."""
    parser = CommandParser(
        prog="blurtrack",
        description="Calibration and validation workbench for gyro-assisted motion deblurring.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CommandParser)
    sub.required = True
    wanted = {m for name, m, _ in COMMANDS if command is None or name == command}
    done: set[str] = set()
    for name, module_name, text in COMMANDS:
        if module_name in wanted:
            if module_name not in done:
                done.add(module_name)
                module = _command_module(module_name)
                if module is not None:
                    module.register(sub)
        elif _installed(module_name):
            sub.add_parser(name, help=text, add_help=False)
    return parser


def _command_module(name: str) -> Any:
    """The command module ``name``, or None where it is not part of this installation."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and name.startswith(exc.name):
            return None  # that command module is not part of this installation
        raise


def _installed(name: str) -> bool:
    """Whether command module ``name`` exists, without running it (its packages' __init__ are
    imported, as for any submodule)."""
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


def command_of(argv: Sequence[str]) -> str:
    """The subcommand an argument list names: its first argument that is not an option
    (``""`` where there is none, e.g. ``blurtrack --help``)."""
    return next((a for a in argv if not a.startswith("-")), "")


#: Optional third-party packages and the extra that installs each (pyproject.toml).
OPTIONAL_EXTRAS: dict[str, str] = {"casadi": "calib", "torch": "gamd", "tensorboard": "gamd"}


def missing_extra_message(exc: ModuleNotFoundError) -> str | None:
    """The one-line advice for a missing optional package, or None for any other import error.

    >>> missing_extra_message(ModuleNotFoundError("x", name="casadi"))
    "this command needs the optional package 'casadi': pip install 'blurtrack[calib]'"
    """
    top = (exc.name or "").split(".")[0]
    extra = OPTIONAL_EXTRAS.get(top)
    if extra is None:
        return None
    return f"this command needs the optional package '{top}': pip install 'blurtrack[{extra}]'"


def quiet_stdout() -> None:
    """Point stdout at /dev/null after its reader went away, so nothing more can fail."""
    import os

    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError):
        pass


def run_command(program: str, args: argparse.Namespace) -> int:
    """Run a parsed command and turn its failures into exit codes, for ``blurtrack`` and
    ``gamd`` alike: a :class:`BlurTrackError`, a disk that cannot take a write or a missing
    optional package is one line on stderr and exit 2 (Python warnings met on the way are
    dropped; after a success they are shown), Ctrl-C exit 130, a closed stdout pipe
    (``| head``) a quiet 141."""
    import warnings

    try:
        # Python warnings (numpy RuntimeWarnings, torch's) are held back while the command
        # runs: shown after a success, dropped after a failure, whose stderr is one line.
        with warnings.catch_warnings(record=True) as held:
            code = int(args.func(args) or 0)
        for w in held:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        sys.stdout.flush()  # a closed pipe (``| head``) shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        quiet_stdout()
        return 141  # 128 + SIGPIPE, as for any pipeline writer whose reader went away
    except BlurTrackError as exc:
        print(f"{program} {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a disk that cannot take a write, met outside the atomic writer
        from blurtrack.io.atomic import DISK_ERRNOS, output_error

        if exc.errno not in DISK_ERRNOS:
            raise
        where = exc.filename if exc.filename is not None else "the output"
        print(f"{program} {args.command}: error: {output_error(where, exc)}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        message = missing_extra_message(exc)
        if message is None:
            raise
        print(f"{program} {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{program} {args.command}: interrupted", file=sys.stderr)
        return 130


def main(argv: Sequence[str] | None = None) -> int:
    """The ``blurtrack`` program; ``argv`` ``None``: this process's own command line, and the
    process's allocator is set for its command (:func:`blurtrack.allocator.keep_heap`)."""
    if argv is None:
        from blurtrack.allocator import keep_heap

        keep_heap()
    args = sys.argv[1:] if argv is None else list(argv)
    code = run_command("blurtrack", build_parser(command_of(args)).parse_args(args))
    if argv is None:
        exit_without_collection()
    return code


def exit_without_collection() -> None:
    """Set this process's objects aside from the cyclic garbage collector: it is about to
    exit. The interpreter's shutdown runs full collections over every object still alive
    (``detect`` on 150 dense frames: 0.10 s of its exit, 0.04 s after this); the objects are
    still released, exit handlers and ``weakref.finalize`` still run, only unreachable
    cycles are left to the operating system (the outputs are written and closed by now)."""
    import gc

    gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
