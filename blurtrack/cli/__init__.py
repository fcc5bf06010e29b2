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
    "blurtrack.cli.demo",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="blurtrack",
        description="Calibration and validation workbench for gyro-assisted motion deblurring.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
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


def quiet_stdout() -> None:
    """Point stdout at /dev/null after its reader went away, so nothing more can fail."""
    import os

    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError):
        pass


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe (``| head``) shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        quiet_stdout()
        return 141  # 128 + SIGPIPE, as for any pipeline writer whose reader went away
    except BlurTrackError as exc:
        print(f"blurtrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"blurtrack {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
