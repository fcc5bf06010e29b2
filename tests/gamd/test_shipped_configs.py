"""Every shipped ``configs/gamd/*.yaml`` parses; the CPU-scale ones train with ``--data DIR``."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from gamd.cli import main
from gamd.config import RunConfig

CONFIGS = sorted((Path(__file__).resolve().parents[2] / "configs" / "gamd").glob("*.yaml"))


def test_configs_are_shipped() -> None:
    assert {p.stem for p in CONFIGS} >= {"gamd_tiny", "gamd_paper", "mimo_pro_tiny"}


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_shipped_config_parses(path: Path) -> None:
    config = RunConfig.from_yaml(path)
    assert config.model.name in path.stem and config.train.steps > 0


@pytest.mark.parametrize(
    "path", [p for p in CONFIGS if p.stem.endswith("_tiny")], ids=lambda p: p.stem
)
def test_tiny_config_trains_one_step_on_a_dataset_given_by_data(
    path: Path, tmp_path: Path, make_dataset, capsys: pytest.CaptureFixture
) -> None:
    crop = RunConfig.from_yaml(path).data.crop
    data = make_dataset(tmp_path / "ds", {"train": 2}, size_hw=(crop + 8, crop + 16))
    out = tmp_path / "run"
    argv = ["train", "--config", str(path), "--data", str(data), "--steps", "1"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["end_step"] == 1 and Path(summary["checkpoint"]).is_file()
    assert "gamd train" in capsys.readouterr().out


def test_shipped_finetune_continues_the_shipped_run_with_its_data_and_restore_options() -> None:
    """Each fine-tune stage (the last ships as gamd.pt) must present data exactly as the run
    it starts from (inference reads the restore options from the checkpoint; the third stage
    adds triplets to its split, nothing else), start from that run's last checkpoint, and
    start no faster; ``bench/train_shipped.py export`` ships the last stage as gamd.pt."""
    from dataclasses import replace

    from blurtrack.testing.bench_script import load_bench_script

    folder = CONFIGS[0].parent
    chain = [
        RunConfig.from_yaml(folder / f"shipped_{run}.yaml")
        for run in ("gamd", "gamd_finetune", "gamd_finetune2", "gamd_finetune3")
    ]
    assert chain[0].train.init_from is None
    for base, fine in itertools.pairwise(chain):
        assert fine.model == base.model
        assert replace(fine.data, split=base.data.split) == base.data
        assert fine.data.restore_options() == base.data.restore_options()
        assert fine.train.init_from == str(Path(base.train.out_dir) / "checkpoints" / "last.pt")
        assert fine.train.out_dir != base.train.out_dir and fine.train.lr <= base.train.lr
        assert fine.train.seed != base.train.seed
    mod = load_bench_script("train_shipped")
    assert mod.EXPORT_RUNS == {"gamd": "gamd_finetune2", "gamd_only": "gamd_only"}
    assert set(mod.RUNS) == {p.stem.removeprefix("shipped_") for p in folder.glob("shipped_*")}
