"""Two runs to one output: the second is refused at once, in one line naming the first's pid,
and writes nothing; a killed first run leaves nothing that blocks the next one. The first run
is a separate process holding the output's lock (blurtrack.io.guard.output_lock, or synth's
dataset lock), the second the command itself in another process."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml

from blurtrack.io.guard import OutputRefusedError, output_lock
from tests.hostile.conftest import REPO, World, all_inputs, assert_refused, run_cli

HOLD = """
import sys, time
from pathlib import Path
if sys.argv[1] == "dataset":
    from blurtrack.synth.store import dataset_lock as lock
    Path(sys.argv[2]).mkdir(parents=True, exist_ok=True)
    cm = lock(Path(sys.argv[2]))
else:
    from blurtrack.io.guard import output_lock
    cm = output_lock(sys.argv[2])
with cm:
    print("locked", flush=True)
    time.sleep(120)
"""


@contextmanager
def held(kind: str, path: Path) -> Iterator[subprocess.Popen[str]]:
    """Another process holding the lock of ``path`` until the block ends (then killed)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    p = subprocess.Popen(
        [sys.executable, "-c", HOLD, kind, str(path)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == "locked"
        yield p
    finally:
        p.kill()
        p.wait(timeout=30)


def _train_config(world: World, tmp_path: Path, out: Path) -> Path:
    cfg = world.train_config()
    cfg["train"]["out_dir"] = str(out)  # type: ignore[index]
    p = tmp_path / "cfg.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


@pytest.mark.parametrize("command", ["calibrate", "gamd train", "synth"])
def test_second_run_to_one_output_is_refused(world: World, tmp_path: Path, command: str) -> None:
    if command == "calibrate":
        out, kind = tmp_path / "c.yaml", "output"
        program, argv = "blurtrack", ["calibrate", str(world.S), "--out", str(out)]
    elif command == "gamd train":
        out, kind = tmp_path / "run", "output"
        program, argv = "gamd", ["train", "--config", str(_train_config(world, tmp_path, out))]
    else:
        out, kind = tmp_path / "ds", "dataset"
        program, argv = "blurtrack", [*world.synth_args(out), "--quiet"]
    before = all_inputs(world)
    with held(kind, out) as first:
        r = run_cli(program, *argv)
        line = assert_refused(r, "is being written by another run")
        assert f"(pid {first.pid})" in line, line
    assert all_inputs(world) == before
    if command == "synth":
        assert not list(out.rglob("*.png")) and not (out / "dataset.yaml").exists()
    else:
        assert not out.exists()


def test_a_killed_run_does_not_block_the_next(tmp_path: Path) -> None:
    """Negative control: once the first process is gone (SIGKILL), the lock is free (its lock
    file may stay behind; the kernel released the lock itself)."""
    out = tmp_path / "c.yaml"
    with (
        held("output", out),
        pytest.raises(OutputRefusedError, match="being written by another run"),
        output_lock(out),
    ):
        pass
    with output_lock(out) as lock:
        assert lock.read_text().strip() == str(os.getpid())
    assert not lock.exists()  # removed when the block ends
