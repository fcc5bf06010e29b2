"""The ``blurtrack`` command line.

Each package registers its own commands: ``blurtrack/cli/<name>.py`` (simulate, import,
validate, detect, report, predict, synth, demo), ``calib/cli.py`` (calibrate) and ``rigs/cli.py``
(record, recover); ``gamd/cli.py`` is the separate ``gamd`` program. Each module exposes
``register(subparsers) -> None``; each registered parser
sets ``func`` to a callable ``(argparse.Namespace) -> int``. The modules of the other packages
(rigs, calib) are imported only when the parser is built, and they import their heavy
dependencies inside their command functions, so ``blurtrack --help`` stays fast.

This is the only layer that prints summaries and chooses exit codes: library code raises
:class:`blurtrack.errors.BlurTrackError` subclasses, which become one line on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import TypeVar

from blurtrack.errors import BlurTrackError

#: Modules that contribute subcommands, in help order. A module that is missing from an
#: installation (an optional package) is skipped, not fatal.
COMMAND_MODULES: tuple[str, ...] = (
    "blurtrack.cli.simulate",
    "blurtrack.cli.importers",
    "blurtrack.cli.validate",
    "blurtrack.cli.detect",
    "calib.cli",
    "blurtrack.cli.report",
    "blurtrack.cli.predict",
    "blurtrack.cli.synth",
    "rigs.cli",
    "blurtrack.cli.export",
    "blurtrack.cli.demo",
)


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


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="blurtrack",
        description="Calibration and validation workbench for gyro-assisted motion deblurring.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CommandParser)
    sub.required = True
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and name.startswith(exc.name):
                continue  # that command module is not part of this installation
            raise
        module.register(sub)
    return parser


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
    ``gamd`` alike: a :class:`BlurTrackError` or a missing optional package is one line on
    stderr and exit 2, Ctrl-C exit 130, a closed stdout pipe (``| head``) a quiet 141."""
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe (``| head``) shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        quiet_stdout()
        return 141  # 128 + SIGPIPE, as for any pipeline writer whose reader went away
    except BlurTrackError as exc:
        print(f"{program} {args.command}: error: {exc}", file=sys.stderr)
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
    return run_command("blurtrack", build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
