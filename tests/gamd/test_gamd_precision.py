"""The GPU training options on the CPU: bf16 autocast and channels_last training steps, and the
paper-preset GPU recipe (configs/gamd/*_paper_gpu.yaml) run and agree with float32."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from gamd.checkpoint import load_checkpoint
from gamd.cli import main
from gamd.config import RunConfig
from gamd.errors import GamdConfigError
from gamd.train import train

REPO = Path(__file__).resolve().parents[2]
GPU_CONFIGS = sorted((REPO / "configs" / "gamd").glob("*_paper_gpu.yaml"))


def _config(root: Path, out: Path, **train_kw) -> RunConfig:
    train_d = {
        "out_dir": str(out),
        "steps": 3,
        "batch_size": 2,
        "lr": 2e-3,
        "seed": 7,
        "checkpoint_every": 3,
        "progress": False,
        "tensorboard": False,
        "device": "cpu",
        **train_kw,
    }
    return RunConfig.from_dict(
        {
            "model": {"name": "gamd", "preset": "tiny"},
            "data": {"root": str(root), "crop": 16, "heat_scale_px": 4.0},
            "train": train_d,
        }
    )


def _rel_weight_gap(a: dict, b: dict, start: dict) -> float:
    """``‖a − b‖ / ‖b − start‖`` over all float weights: how far apart two runs ended,
    relative to how far training moved them (Adam's sign-like steps make single elements
    of near-zero gradient meaningless)."""
    keys = [k for k, v in a.items() if v.is_floating_point()]
    gap = torch.cat([(a[k] - b[k]).flatten() for k in keys]).norm()
    moved = torch.cat([(b[k] - start[k]).flatten() for k in keys]).norm()
    return float(gap / moved)


@pytest.fixture(scope="module")
def fp32(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("fp32")
    res = train(_config(tiny_dataset, out))
    torch.manual_seed(7)
    from gamd.nets import build_model

    start = build_model("gamd", "tiny").state_dict()
    return res, load_checkpoint(out / "checkpoints/last.pt")["model"], start


def test_bf16_autocast_steps_are_finite_and_close_to_fp32(fp32, tiny_dataset, tmp_path) -> None:
    ref, ref_w, start = fp32
    res = train(_config(tiny_dataset, tmp_path / "bf16", amp="bf16"))
    w = load_checkpoint(tmp_path / "bf16/checkpoints/last.pt")["model"]
    assert all(torch.isfinite(torch.tensor(res.losses)))
    assert all(v.dtype == ref_w[k].dtype for k, v in w.items())  # weights stay float32
    # Same data and initial weights: the losses agree to bf16 precision (8-bit mantissa) ...
    for a, b in zip(res.losses, ref.losses, strict=True):
        assert a == pytest.approx(b, rel=2e-2)
    # ... but autocast did run in bf16 (negative control: not the float32 numbers).
    assert res.losses != ref.losses
    # The weights end near the float32 ones, nearer than float32 steps with a learning rate
    # 1.5 times as large do (control: same initial weights and batches).
    train(_config(tiny_dataset, tmp_path / "other", lr=3e-3))
    w_other = load_checkpoint(tmp_path / "other/checkpoints/last.pt")["model"]
    gap, control = _rel_weight_gap(w, ref_w, start), _rel_weight_gap(w_other, ref_w, start)
    assert gap < 0.5 and gap < control / 2


def test_channels_last_steps_match_fp32(fp32, tiny_dataset, tmp_path) -> None:
    ref, ref_w, start = fp32
    res = train(_config(tiny_dataset, tmp_path / "cl", channels_last=True))
    conv = next(m for m in res.model.modules() if isinstance(m, torch.nn.Conv2d))
    assert conv.weight.is_contiguous(memory_format=torch.channels_last)
    w = load_checkpoint(tmp_path / "cl/checkpoints/last.pt")["model"]
    for a, b in zip(res.losses, ref.losses, strict=True):
        assert a == pytest.approx(b, rel=1e-4)
    assert _rel_weight_gap(w, ref_w, start) < 1e-2
    both = train(_config(tiny_dataset, tmp_path / "both", channels_last=True, amp="bf16"))
    for a, b in zip(both.losses, ref.losses, strict=True):
        assert a == pytest.approx(b, rel=2e-2)


def test_gpu_configs_are_the_paper_preset_with_gpu_options() -> None:
    assert {p.stem for p in GPU_CONFIGS} == {"gamd_paper_gpu", "gamd_only_paper_gpu"}
    for path in GPU_CONFIGS:
        c = RunConfig.from_yaml(path)
        paper = RunConfig.from_yaml(path.with_name(path.name.replace("_gpu", "")))
        assert c.model == paper.model and c.model.preset == "paper"
        assert (c.train.amp, c.train.channels_last, c.train.device) == ("bf16", True, "cuda")
        assert c.train.steps == paper.train.steps and c.train.milestones == paper.train.milestones
        assert c.train.batch_size == 1  # per process: 8 GPUs make the paper's batch of 8
        assert c.data.gate_px is not None and c.data.recentre


@pytest.mark.parametrize("path", GPU_CONFIGS, ids=lambda p: p.stem)
def test_gpu_recipe_runs_a_step_on_the_cpu(path: Path, make_dataset, tmp_path: Path) -> None:
    """The paper-size network with bf16 autocast and channels_last, one step on the CPU
    (``--device cpu``; small images instead of 256-px crops)."""
    text = (
        path.read_text()
        .replace("crop: 256", "crop: 32")
        .replace("num_workers: 6", "num_workers: 0")
    )
    cfg = tmp_path / "gpu.yaml"
    cfg.write_text(text)
    data = make_dataset(tmp_path / "ds", {"train": 2}, size_hw=(40, 48))
    out = tmp_path / "run"
    argv = ["train", "--config", str(cfg), "--data", str(data), "--steps", "1", "--out", str(out)]
    if not torch.cuda.is_available():
        with pytest.raises(GamdConfigError, match="no CUDA device"):
            train(RunConfig.from_yaml(cfg))
    assert main([*argv, "--device", "cpu", "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["end_step"] == 1 and torch.isfinite(torch.tensor(summary["final_loss_mean10"]))
    state = load_checkpoint(summary["checkpoint"])
    assert (
        state["config"]["train"]["amp"] == "bf16" and state["config"]["model"]["preset"] == "paper"
    )
