"""The CLI's exit: the process's objects are set aside from the cyclic collector once its own
command has run (``blurtrack.cli.exit_without_collection``), and only then."""

from __future__ import annotations

import gc
import sys
import weakref

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


class _Node:
    """An object that can hold a reference to itself (a cycle only the collector frees)."""

    other: object = None


def test_a_cycle_set_aside_is_left_to_the_exit_and_freed_without_the_freeze() -> None:
    # What the freeze saves the shutdown: collecting the cycles alive at the end. A cycle
    # set aside survives a full collection; once back (negative control), it is freed.
    gc.disable()  # no automatic collection between making the cycle and the freeze
    try:
        node = _Node()
        node.other = node
        gone = weakref.ref(node)
        del node
        cli.exit_without_collection()
        gc.collect()
        assert gone() is not None
        gc.unfreeze()
        gc.collect()
        assert gone() is None
    finally:
        gc.unfreeze()
        gc.enable()


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
