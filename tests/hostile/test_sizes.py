"""Absurd sizes are refused before anything is allocated, with the bound in the one line:
GAMD network width / depth / batch / crop, synth's triplet size (times its workers),
simulate's frame size (times its workers). The rule (blurtrack/io/bounds.py): the estimated
memory must stay under half of this machine's; the tests pin the machine to 1 GiB or 64 GiB
(monkeypatched) so they mean the same everywhere."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from blurtrack.cli import main
from blurtrack.errors import BoundsError
from blurtrack.io import bounds
from tests.hostile.conftest import World, all_inputs, debris

GIB = 2**30


@pytest.fixture
def one_gib(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bounds, "memory_bytes", lambda: GIB)


def test_training_estimate_lets_real_configs_through(monkeypatch: pytest.MonkeyPatch) -> None:
    """Negative controls: the shipped tiny config on a 1 GiB machine and the paper's sizes
    (base 32, 8 residual units, batch 8, crop 256) on a 64 GiB one pass; width 1e6 does not."""
    monkeypatch.setattr(bounds, "memory_bytes", lambda: GIB)
    bounds.check_training_size(8, 1, 4, 64)
    monkeypatch.setattr(bounds, "memory_bytes", lambda: 64 * GIB)
    bounds.check_training_size(32, 8, 8, 256)
    assert bounds.training_memory_bytes(32, 8, 8, 256) > bounds.training_memory_bytes(8, 1, 4, 64)
    with pytest.raises(BoundsError, match=r"base_channels 1000000.*more than half of this"):
        bounds.check_training_size(1_000_000, 8, 8, 256)


@pytest.mark.parametrize(
    ("model", "data", "train"),
    [
        ({"base_channels": 1_000_000}, {}, {}),
        ({"num_res": 100_000}, {}, {}),
        ({}, {}, {"batch_size": 1_000_000}),
        ({}, {"crop": 100_000}, {}),
    ],
    ids=["width", "depth", "batch", "crop"],
)
def test_gamd_train_refuses_absurd_sizes(
    world: World,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    one_gib: None,
    model: dict[str, int],
    data: dict[str, int],
    train: dict[str, int],
) -> None:
    from gamd.cli import main as gamd_main

    cfg = world.train_config(**model)
    cfg["data"].update(data)  # type: ignore[attr-defined]
    cfg["train"].update(train, out_dir=str(tmp_path / "run"))  # type: ignore[attr-defined]
    p = tmp_path / "cfg.yaml"
    p.write_text(yaml.safe_dump(cfg))
    before = all_inputs(world)
    rc = gamd_main(["train", "--config", str(p)])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "more than half of this machine's 1.0 GiB" in err[0], err[0]
    assert not (tmp_path / "run").exists() and all_inputs(world) == before


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--size", "8192x8192"], "8192x8192 px triplets in 1 worker"),
        (["--size", "2048x2048", "--workers", "64"], "in 64 worker(s)"),
        (["--size", "100000x100000"], "sides in [16, 8192]"),
        (["--count", "1000000000"], "count must be in [1, 1000000]"),
    ],
)
def test_synth_refuses_absurd_sizes(
    world: World,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    one_gib: None,
    extra: list[str],
    needle: str,
) -> None:
    out = tmp_path / "ds"
    rc = main([*world.synth_args(out), *extra])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0], err
    assert not (out / "dataset.yaml").exists() and debris(tmp_path) == []


def test_synth_size_negative_control(world: World, tmp_path: Path, one_gib: None) -> None:
    """The small sizes of the other tests pass the same bound on a 1 GiB machine."""
    assert main([*world.synth_args(tmp_path / "ds"), "--quiet"]) == 0


@pytest.mark.parametrize(
    ("size", "workers", "needle"),
    [
        ((7000, 7000), 1, "7000x7000 px frames in 1 worker"),
        ((1000, 1000), 64, "1000x1000 px frames in 64 worker"),
        ((10000, 10000), 1, "image larger than 50 Mpx"),
    ],
)
def test_simulate_refuses_absurd_frame_sizes(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    one_gib: None,
    size: tuple[int, int],
    workers: int,
    needle: str,
) -> None:
    preset = tmp_path / "big.yaml"
    preset.write_text(yaml.safe_dump({"base": "clean", "width": size[0], "height": size[1]}))
    out = tmp_path / "sim"
    argv = ["simulate", str(out), "--preset-file", str(preset), "--frames", "2"]
    rc = main([*argv, "--workers", str(workers)])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0], err
    assert not out.exists() and debris(tmp_path) == []


def test_simulate_refuses_absurd_frame_counts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["simulate", str(tmp_path / "sim"), "--frames", "1000000000"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and "frames must be in [1," in err[0], err
    assert not (tmp_path / "sim").exists()
