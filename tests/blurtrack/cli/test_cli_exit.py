"""The CLI's exit: the process's objects are set aside from the cyclic collector once its own
command has run (``blurtrack.cli.exit_without_collection``), and only then."""

from __future__ import annotations

import gc
import sys

import pytest

import blurtrack.cli as cli


def test_exit_without_collection_freezes_and_keeps_objects() -> None:
    kept = [object() for _ in range(10)]
    before = gc.get_freeze_count()
    try:
        cli.exit_without_collection()
        assert gc.get_freeze_count() > before
        assert gc.collect() >= 0 and all(k is not None for k in kept)
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0


def test_only_the_process_own_command_freezes(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    monkeypatch.setattr(cli, "exit_without_collection", lambda: calls.append("freeze"))

    def run_command(program: str, args: object) -> int:
        calls.append("run")
        return 3

    monkeypatch.setattr(cli, "run_command", run_command)
    monkeypatch.setattr("blurtrack.allocator.keep_heap", lambda: True)
    # a command called from Python (tests, other tools) goes on collecting
    assert cli.main(["validate", "somewhere"]) == 3
    assert calls == ["run"]
    # the process's own command line: after the command, with its exit code kept
    monkeypatch.setattr(sys, "argv", ["blurtrack", "validate", "somewhere"])
    assert cli.main() == 3
    assert calls == ["run", "run", "freeze"]
