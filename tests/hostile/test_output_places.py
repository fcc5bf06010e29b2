"""Outputs inside recordings, inside a command's own input folders, and through a session's
``derived/`` link: every command that writes is refused through the one guard
(blurtrack/io/guard.py) with one line, exit 2, nothing written and every input unchanged."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import yaml

from blurtrack.cli import main
from tests.hostile.conftest import World, all_inputs, debris, tree_hashes


def _gamd(argv: list[str]) -> int:
    from gamd.cli import main as gamd_main

    return gamd_main(argv)


def _fill(w: World, t: Path, text: str) -> str:
    names = {"S": w.S, "S2": w.S2, "calib": w.calib, "images": w.images, "data": w.data}
    names.update(config=w.config, T=t)
    return text.format(**{k: str(v) for k, v in names.items()})


#: (case, program, argv with {S} {S2} {calib} {images} {data} {config} {T}, the output)
CASES = [
    ("export SESSION/x.bag", "bt", "export rosbag {S} {S}/x.bag", "{S}/x.bag"),
    ("export SESSION/cam0/x.bag", "bt", "export rosbag {S} {S}/cam0/x.bag", "{S}/cam0/x.bag"),
    ("export into another session", "bt", "export rosbag {S} {S2}/imu0/x.bag", "{S2}/imu0/x.bag"),
    ("export --ros2 SESSION/bag", "bt", "export rosbag {S} {S}/bag --ros2", "{S}/bag"),
    ("calibrate SESSION/c.yaml", "bt", "calibrate {S} --out {S}/c.yaml", "{S}/c.yaml"),
    ("report SESSION/r", "bt", "report {S} --calib {calib} --out {S}/r", "{S}/r"),
    ("predict SESSION/cam0/p", "bt", "predict {S} --calib {calib} --out {S}/cam0/p", "{S}/cam0/p"),
    ("synth SESSION/ds", "synth", "{S}/ds", "{S}/ds"),
    ("synth inside --images", "synth", "{images}/ds", "{images}/ds"),
    ("demo SESSION/demo", "bt", "demo --out {S}/demo", "{S}/demo"),
    ("gamd train out_dir SESSION/run", "gamd", "train --config {T}/cfg.yaml", "{S}/run"),
    ("gamd train SESSION/cam0/x", "gamd", "train --config {config} --out {S}/cam0/x", "{S}/cam0/x"),
    ("gamd train inside dataset", "gamd", "train --config {config} --out {data}/run", "{data}/run"),
    ("gamd eval inside its dataset", "gamd", "eval --data {data} --out {data}/ev", "{data}/ev"),
]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_output_inside_a_recording_or_an_input_is_refused(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str], case: tuple[str, ...]
) -> None:
    _, program, template, out = case
    target = Path(_fill(world, tmp_path, out))
    cfg = world.train_config()
    cfg["train"]["out_dir"] = str(world.S / "run")  # type: ignore[index]
    (tmp_path / "cfg.yaml").write_text(yaml.safe_dump(cfg))
    before = all_inputs(world)
    if program == "synth":
        rc = main(world.synth_args(target))
    else:
        argv = _fill(world, tmp_path, template).split()
        rc = (_gamd if program == "gamd" else main)(argv)
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "inside" in err[0], err[0]
    assert not target.exists(), f"{target} was written"
    assert all_inputs(world) == before
    assert debris(world.root) == []


def test_export_to_a_good_path_succeeds(world: World, tmp_path: Path) -> None:
    """Negative control: the same export to a folder of its own works, companions beside it."""
    before = all_inputs(world)
    assert main(["export", "rosbag", str(world.S), str(tmp_path / "x.bag"), "--quiet"]) == 0
    assert (tmp_path / "x.bag").is_file() and (tmp_path / "x.camchain.yaml").is_file()
    assert all_inputs(world) == before and debris(tmp_path) == []


def _session_copy(world: World, tmp_path: Path, with_table: bool = True) -> Path:
    s = tmp_path / "S"
    shutil.copytree(world.S, s)
    if not with_table:
        (s / "streaks.parquet").unlink()
    return s


@pytest.mark.parametrize("where", ["other session's cam0", "outside"])
def test_detect_refuses_a_derived_link(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    """``SESSION/derived`` a link to another session's ``cam0/`` or to any folder outside:
    detect (whose summary goes into derived/) is refused, nothing written through it."""
    s = _session_copy(world, tmp_path)
    (s / "streaks.parquet").unlink()
    other = tmp_path / "S2"
    shutil.copytree(world.S2, other)
    target = other / "cam0" if where != "outside" else tmp_path / "elsewhere"
    target.mkdir(exist_ok=True)
    (s / "derived").symlink_to(target, target_is_directory=True)
    before, before_other = tree_hashes(s), tree_hashes(other)
    listing = sorted(os.listdir(target))
    rc = main(["detect", str(s), "--quiet"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and "is a link" in err[0], err
    assert sorted(os.listdir(target)) == listing, "written through the link"
    assert tree_hashes(s) == before and tree_hashes(other) == before_other
    assert not (s / "streaks.parquet").exists()


def test_calibrate_detecting_first_refuses_a_derived_link(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """calibrate on a session without a table detects first into SESSION/streaks.parquet and
    SESSION/derived/: a derived link is refused before anything is written."""
    s = _session_copy(world, tmp_path, with_table=False)
    (tmp_path / "elsewhere").mkdir()
    (s / "derived").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    before = tree_hashes(s)
    rc = main(["calibrate", str(s), "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and "is a link" in err[0], err
    assert os.listdir(tmp_path / "elsewhere") == [] and tree_hashes(s) == before
    assert not (tmp_path / "c.yaml").exists()


def test_detect_with_a_real_derived_folder_succeeds(world: World, tmp_path: Path) -> None:
    """Negative control: the same detect with derived/ a real folder writes its summary there."""
    s = _session_copy(world, tmp_path)
    (s / "streaks.parquet").unlink()
    (s / "derived").mkdir()
    recorded = {k: v for k, v in tree_hashes(s).items() if not k.startswith("derived")}
    assert main(["detect", str(s), "--quiet", "--workers", "1"]) == 0
    assert (s / "derived" / "streaks.summary.json").is_file()
    after = tree_hashes(s)
    assert {k: after[k] for k in recorded} == recorded


@pytest.mark.parametrize("command", ["predict", "report", "gamd deblur"])
def test_other_writers_into_derived_refuse_a_link(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """Whatever writes into ``SESSION/derived/`` goes through the same guard."""
    s = _session_copy(world, tmp_path)
    (tmp_path / "elsewhere").mkdir()
    (s / "derived").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    out = s / "derived" / "x"
    if command == "gamd deblur":
        rc = _gamd(["deblur", str(s), "--out", str(out)])
    else:
        rc = main([command, str(s), "--calib", str(world.calib), "--out", str(out)])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and "is a link" in err[0], err
    assert os.listdir(tmp_path / "elsewhere") == []
