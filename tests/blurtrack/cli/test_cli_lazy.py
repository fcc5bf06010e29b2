"""The ``blurtrack`` parser built lazily (only the named command's module imported) has the
same help, top-level and per command, as the parser of every module, and ``blurtrack
calibrate`` starts without importing the other commands' modules or their heavy packages."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from blurtrack.cli import COMMANDS, build_parser, command_of

REPO = Path(__file__).resolve().parents[3]
FULL = build_parser()


def _tree(parser: argparse.ArgumentParser, prefix: str = ""):
    """Every (sub)parser below ``parser`` by its command path, with its help text."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix}{name}", sub
                yield from _tree(sub, f"{prefix}{name} ")


def _listing(parser: argparse.ArgumentParser) -> list[tuple[str, str | None]]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return [(c.dest, c.help) for c in sub._choices_actions]


def test_the_declarations_are_the_modules_commands_in_order() -> None:
    assert _listing(FULL) == [(name, text) for name, _, text in COMMANDS]


def test_top_level_help_is_the_same_without_importing_any_command() -> None:
    lazy = build_parser(command_of(["--help"]))
    assert lazy.format_help() == FULL.format_help()
    assert _listing(lazy) == _listing(FULL)


@pytest.mark.parametrize("name", [name for name, _, _ in COMMANDS])
def test_each_command_parses_and_helps_as_in_the_full_parser(name: str) -> None:
    lazy = dict(_tree(build_parser(name)))
    full = dict(_tree(FULL))
    mine = {k: v for k, v in lazy.items() if k == name or k.startswith(name + " ")}
    assert mine and set(mine) == {k for k in full if k == name or k.startswith(name + " ")}
    for path, parser in mine.items():
        assert parser.format_help() == full[path].format_help(), path
    assert callable(mine[name].get_default("func")) or len(mine) > 1  # import has subcommands
    # the other modules' commands are listed only: no options, no handler
    module = {n: m for n, m, _ in COMMANDS}
    others = [p for k, p in lazy.items() if module.get(k.split()[0]) != module[name]]
    assert others and all(p.get_default("func") is None for p in others)


def test_command_of_is_the_first_positional_argument() -> None:
    assert command_of(["calibrate", "S", "--out", "c.yaml"]) == "calibrate"
    assert command_of(["-h"]) == ""
    assert command_of([]) == ""


def _modules_after(code: str) -> set[str]:
    script = f"import sys\n{code}\nprint(' '.join(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, check=True
    )
    return set(out.stdout.split())


#: Modules that ``blurtrack calibrate`` has no use for at start-up (argument parsing).
NOT_AT_STARTUP = (
    "torch",
    "gamd",
    "dask",
    "distributed",
    "cv2",
    "casadi",
    "pandas",
    "scipy",
    "matplotlib",
    "serial",
    "rosbags",
    "rigs.cli",
    "blurtrack.cli.synth",
    "blurtrack.cli.demo",
    "blurtrack.cli.detect",
    "blurtrack.cli.importers",
)


def _unneeded(mods: set[str]) -> list[str]:
    return sorted(n for n in NOT_AT_STARTUP if n in mods)


def test_calibrate_startup_imports_only_what_it_needs() -> None:
    code = (
        "from blurtrack.cli import main\n"
        "try:\n    main(['calibrate', '--help'])\nexcept SystemExit:\n    pass"
    )
    mods = _modules_after(code)
    assert "calib.cli" in mods  # the command itself was built
    assert _unneeded(mods) == []
    # negative control: the full parser imports every command's module
    full = _modules_after("import blurtrack.cli\nblurtrack.cli.build_parser()")
    assert {"rigs.cli", "blurtrack.cli.synth", "blurtrack.cli.demo"} <= set(_unneeded(full))
