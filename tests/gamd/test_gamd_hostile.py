"""Hostile input to gamd (issue 20): runs are never overwritten without --force, NaN or
malformed checkpoints fail with one line and exit 2, and no message advises an unsafe load."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch
import yaml

from gamd.checkpoint import load_checkpoint, save_checkpoint
from gamd.cli import main

REPO = Path(__file__).resolve().parents[2]


def _write_config(root: Path, tmp_path: Path) -> Path:
    cfg = {
        "model": {"name": "gamd_only", "preset": "tiny"},
        "data": {"root": str(root), "crop": 16, "heat_scale_px": 4.0},
        "train": {
            "out_dir": str(tmp_path / "run"),
            "steps": 2,
            "batch_size": 1,
            "lr": 1e-3,
            "checkpoint_every": 1,
            "progress": False,
            "tensorboard": False,
        },
    }
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _hashes(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _one_line_error(capsys, prefix: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(prefix), err
    assert "Traceback" not in err and "weights_only=False" not in err
    return err


@pytest.fixture(scope="module")
def trained(tiny_dataset, tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("hostile")
    cfg = _write_config(tiny_dataset, tmp)
    assert main(["train", "--config", str(cfg), "--no-progress"]) == 0
    return cfg, tmp / "run"


def test_train_refuses_an_existing_run_without_resume_or_force(trained, capsys) -> None:
    cfg, run = trained
    before = _hashes(run)
    capsys.readouterr()
    assert main(["train", "--config", str(cfg), "--no-progress"]) == 2
    err = _one_line_error(capsys, "gamd train: error: ")
    assert "--resume" in err and "--force" in err
    assert _hashes(run) == before  # nothing overwritten
    assert main(["train", "--config", str(cfg), "--no-progress", "--resume", "auto"]) == 0
    assert _hashes(run)["checkpoints/last.pt"] == before["checkpoints/last.pt"]  # at its end


def test_force_starts_over(trained, tmp_path, capsys) -> None:
    cfg, _ = trained
    other = tmp_path / "forced"
    assert main(["train", "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    assert main(["train", "--config", str(cfg), "--out", str(other), "--force"]) == 0
    assert load_checkpoint(other / "checkpoints/last.pt")["step"] == 2


def _tamper(src: Path, dst: Path, **changes) -> Path:
    state = load_checkpoint(src)
    for key, value in changes.items():
        if value is None:
            state.pop(key)
        elif callable(value):
            state[key] = value(state[key])
        else:
            state[key] = value
    state.pop("format")
    return save_checkpoint(dst, state)


def _nan_weights(model: dict) -> dict:
    model = dict(model)
    k = next(iter(model))
    model[k] = torch.full_like(model[k], float("nan"))
    return model


@pytest.mark.parametrize(
    "case, changes",
    [
        ("nan weights", {"model": _nan_weights}),
        ("step is text", {"step": "many"}),
        ("step negative", {"step": -3}),
        ("model not a mapping", {"model": [1, 2]}),
        ("model values not tensors", {"model": lambda m: {k: 1.0 for k in m}}),
        ("config not a mapping", {"config": "gamd"}),
        ("config without model", {"config": lambda c: {"data": c["data"], "train": c["train"]}}),
        ("missing step", {"step": None}),
        ("rng not bytes", {"rng_cpu": torch.zeros(3)}),
    ],
)
def test_bad_checkpoints_fail_with_one_line(
    trained, tiny_dataset, tmp_path, capsys, case, changes
) -> None:
    _, run = trained
    bad = _tamper(run / "checkpoints/last.pt", tmp_path / "bad.pt", **changes)
    capsys.readouterr()
    argv = ["eval", "--checkpoint", str(bad), "--data", str(tiny_dataset)]
    assert main([*argv, "--out", str(tmp_path / "ev"), "--no-progress"]) == 2, case
    _one_line_error(capsys, "gamd eval: error: ")
    assert not (tmp_path / "ev" / "summary.json").exists()


def test_malformed_resume_state_is_one_line(trained, tmp_path, capsys) -> None:
    cfg, run = trained
    out = tmp_path / "r"
    (out / "checkpoints").mkdir(parents=True)
    _tamper(run / "checkpoints/last.pt", out / "checkpoints/last.pt", step=1, optimizer={"x": 1})
    capsys.readouterr()
    argv = ["train", "--config", str(cfg), "--out", str(out), "--resume", "auto"]
    assert main([*argv, "--no-progress"]) == 2
    _one_line_error(capsys, "gamd train: error: ")


def test_unsafe_pickle_message_does_not_advise_unsafe_loading(tmp_path, capsys) -> None:
    import argparse

    torch.save({"format": "gamd-checkpoint/1", "x": argparse.Namespace(a=1)}, tmp_path / "e.pt")
    assert main(["eval", "--checkpoint", str(tmp_path / "e.pt"), "--data", "x", "--out", "o"]) == 2
    err = _one_line_error(capsys, "gamd eval: error: refusing checkpoint")
    assert "weights_only" not in err
