"""Full and read-only disks under the commands that write the most: synth, gamd train, export
rosbag, calibrate, detect. One line naming the problem, exit 2, no traceback, no file (whole or
half) at the target path and no temporary left beside it, inputs unchanged.

A full disk is a file size limit (``RLIMIT_FSIZE`` in the child, ``SIGXFSZ`` ignored, so a
write past it fails with ``EFBIG`` like a disk that has no room for the file); a read-only
folder is a read-only tmpfs where the tests run as root, else mode 0555 (conftest)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from tests.hostile.conftest import World, all_inputs, assert_refused, debris, run_cli


def _train_config(world: World, tmp_path: Path, out: Path) -> Path:
    cfg = world.train_config()
    cfg["train"]["out_dir"] = str(out)  # type: ignore[index]
    p = tmp_path / "train.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def _argv(world: World, tmp_path: Path, command: str, out: Path) -> tuple[str, list[str]]:
    """(program, argv) of ``command`` writing its result to ``out``."""
    if command == "synth":
        return "blurtrack", [*world.synth_args(out), "--quiet"]
    if command == "gamd train":
        return "gamd", ["train", "--config", str(_train_config(world, tmp_path, out))]
    if command == "export":
        return "blurtrack", ["export", "rosbag", str(world.S), str(out), "--quiet"]
    if command == "calibrate":
        return "blurtrack", ["calibrate", str(world.S), "--out", str(out)]
    return "blurtrack", ["detect", str(world.S), "--out", str(out), "--quiet", "--workers", "1"]


#: command -> (output name, file size limit (bytes) smaller than its main output, the files
#: under the output that must not exist after the failure)
FULL = {
    "synth": ("ds", 16384, "**/heat/*.npy"),
    "gamd train": ("run", 20000, "**/*.pt"),
    "export": ("x.bag", 16384, "x.bag"),
    "calibrate": ("c.yaml", 1024, "c.yaml"),
    "detect": ("t.parquet", 1024, "t.parquet"),
}


@pytest.mark.parametrize("command", list(FULL))
def test_full_disk(world: World, tmp_path: Path, command: str) -> None:
    name, limit, pattern = FULL[command]
    out = tmp_path / "out" / name
    out.parent.mkdir()
    program, argv = _argv(world, tmp_path, command, out)
    before = all_inputs(world)
    r = run_cli(program, *argv, fsize=limit)
    line = assert_refused(r)
    assert "no space left" in line, line
    assert list((tmp_path / "out").glob(pattern)) == [], "a (half) result at the target path"
    assert debris(tmp_path) == []
    assert all_inputs(world) == before


@pytest.mark.parametrize("command", ["synth", "export", "calibrate"])
def test_full_disk_negative_control(world: World, tmp_path: Path, command: str) -> None:
    """The same commands without the limit succeed (the limit, not the case, made them fail)."""
    name = FULL[command][0]
    out = tmp_path / "out" / name
    out.parent.mkdir()
    program, argv = _argv(world, tmp_path, command, out)
    r = run_cli(program, *argv)
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.exists() and debris(tmp_path) == []


@pytest.mark.parametrize("command", list(FULL))
def test_read_only_output_folder(
    world: World, tmp_path: Path, readonly_dir: Path, command: str
) -> None:
    out = readonly_dir / FULL[command][0]
    program, argv = _argv(world, tmp_path, command, out)
    before = all_inputs(world)
    r = run_cli(program, *argv)
    line = assert_refused(r)
    assert "not writable" in line or "read-only" in line, line
    assert not out.exists() and all_inputs(world) == before
