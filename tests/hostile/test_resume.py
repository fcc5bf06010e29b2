"""Resume trusts only complete outputs: a zero-byte, truncated or undecodable file left by an
earlier run is never counted as done. ``synth`` makes such triplets again and says so;
``gamd train --resume auto`` passes over a broken ``last.pt`` to the newest complete
checkpoint and says so, and refuses in one line when none is complete."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from blurtrack.cli import main
from blurtrack.synth.store import intact, read_manifest
from tests.hostile.conftest import World, all_inputs, debris


def _files(ds: Path) -> dict[int, dict[str, Path]]:
    recs = read_manifest(ds / "manifest.jsonl")
    return {i: {k: ds / rel for k, rel in r["files"].items()} for i, r in recs.items()}


def _decodes(files: dict[str, Path]) -> bool:
    ok = all(
        cv2.imdecode(np.frombuffer(files[k].read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
        is not None
        for k in ("sharp", "blur")
    )
    return ok and np.load(files["heat"]).shape[0] == 6


def test_synth_remakes_broken_triplets_and_says_so(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds = tmp_path / "ds"
    assert main([*world.synth_args(ds), "--quiet"]) == 0
    capsys.readouterr()
    files = _files(ds)
    good = {i: {k: p.read_bytes() for k, p in f.items()} for i, f in files.items()}
    files[0]["blur"].write_bytes(b"")  # zero bytes
    heat = files[1]["heat"].read_bytes()
    files[1]["heat"].write_bytes(heat[: len(heat) // 2])  # truncated
    files[2]["sharp"].write_bytes(np.random.default_rng(0).bytes(500))  # undecodable
    assert not any(intact(files[i][k]) for i, k in ((0, "blur"), (1, "heat"), (2, "sharp")))
    before = all_inputs(world)
    assert main([*world.synth_args(ds), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "3 made, 0 already done" in out, out
    assert "made 3 finished triplet(s) again" in out and "0, 1, 2" in out, out
    again = _files(ds)
    assert all(_decodes(f) for f in again.values())
    # deterministic by (spec, index): the remade files equal the first ones
    assert {i: {k: p.read_bytes() for k, p in f.items()} for i, f in again.items()} == good
    summary = json.loads((ds / "summary.json").read_text())
    assert summary["remade_broken"] == [0, 1, 2]
    assert all_inputs(world) == before and debris(tmp_path) == []
    # negative control: a complete dataset is skipped whole, nothing remade
    assert main([*world.synth_args(ds), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "0 made, 3 already done" in out and "again" not in out, out


def test_intact_reads_heads_and_tails_only(tmp_path: Path) -> None:
    png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1].tobytes()
    (tmp_path / "a.png").write_bytes(png)
    (tmp_path / "b.png").write_bytes(png[:-1])
    np.save(tmp_path / "a.npy", np.zeros((6, 4, 4), np.float32))
    raw = (tmp_path / "a.npy").read_bytes()
    (tmp_path / "b.npy").write_bytes(raw + b"x")
    (tmp_path / "c.npy").write_bytes(raw[:20])
    assert intact(tmp_path / "a.png") and intact(tmp_path / "a.npy")
    assert not any(intact(tmp_path / n) for n in ("b.png", "b.npy", "c.npy", "missing.png"))


def _config(world: World, tmp_path: Path, steps: int) -> Path:
    cfg = world.train_config()
    cfg["train"].update(  # type: ignore[attr-defined]
        out_dir=str(tmp_path / "run"), steps=steps, checkpoint_every=1, progress=False
    )
    p = tmp_path / f"cfg{steps}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def test_gamd_resume_passes_over_a_broken_last_checkpoint(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gamd.checkpoint import load_checkpoint
    from gamd.cli import main as gamd_main

    assert gamd_main(["train", "--config", str(_config(world, tmp_path, 2))]) == 0
    ckpts = tmp_path / "run" / "checkpoints"
    last = ckpts / "last.pt"
    last.write_bytes(last.read_bytes()[:100])  # a run killed mid-write by another tool
    capsys.readouterr()
    argv = ["train", "--config", str(_config(world, tmp_path, 3)), "--resume", "auto"]
    assert gamd_main(argv) == 0
    out = capsys.readouterr().out
    assert "passed over 1" in out and "last.pt" in out and "step_0000002.pt" in out, out
    assert int(load_checkpoint(last)["step"]) == 3
    # only broken checkpoints: one line, exit 2
    for p in ckpts.glob("*.pt"):
        p.write_bytes(b"")
    argv = ["train", "--config", str(_config(world, tmp_path, 4)), "--resume", "auto"]
    assert gamd_main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "no complete checkpoint" in err[0], err
