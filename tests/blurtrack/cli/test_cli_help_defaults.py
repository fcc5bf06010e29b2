"""Every ``blurtrack`` subcommand's ``--help`` names the default of each option that has one."""

from __future__ import annotations

import argparse

import pytest

from blurtrack.cli import build_parser, has_shown_default


def _subparsers(parser: argparse.ArgumentParser, prefix: str = "blurtrack"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix} {name}", sub
                yield from _subparsers(sub, f"{prefix} {name}")


def _spellings(default: object) -> list[str]:
    out = [str(default)]
    if isinstance(default, float):
        out += [f"{default:g}", f"{default:.0f}"]
    if isinstance(default, (list, tuple)):
        out.append(",".join(str(v) for v in default))
    return out


COMMANDS = dict(_subparsers(build_parser()))


def test_every_registered_command_is_checked() -> None:
    for name in ("simulate", "detect", "calibrate", "report", "predict", "synth", "demo"):
        assert f"blurtrack {name}" in COMMANDS


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_shows_each_default(name: str) -> None:
    parser = COMMANDS[name]
    text = parser.format_help()  # renders every %(default)s without error
    assert "usage:" in text
    formatter = parser._get_formatter()
    missing = []
    for action in parser._actions:
        if not has_shown_default(action):
            continue
        shown = formatter._expand_help(action)
        if not any(s in shown for s in _spellings(action.default)):
            missing.append(f"{action.option_strings[-1]}={action.default!r}: {shown!r}")
    assert not missing, f"{name}: options whose help hides the default: {missing}"


def test_help_mentions_the_detect_default_table() -> None:
    text = " ".join(COMMANDS["blurtrack detect"].format_help().split())
    assert "SESSION/streaks.parquet" in text
    report = " ".join(COMMANDS["blurtrack report"].format_help().split())
    assert "detected first" in report
