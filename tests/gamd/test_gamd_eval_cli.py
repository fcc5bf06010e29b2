"""Evaluation metrics, the gamd CLI (train, eval) and its error handling."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from skimage.metrics import structural_similarity

from gamd.cli import main
from gamd.data import DeblurDataset
from gamd.evaluate import evaluate, psnr_ssim, summary_table
from gamd.nets import DeblurNet


class Oracle(DeblurNet):
    """Returns a fixed image: lets the evaluation be checked against known values."""

    OUTPUT_SCALES = (1,)

    def __init__(self, image: torch.Tensor) -> None:
        super().__init__()
        self.image = image
        self.dummy = torch.nn.Parameter(torch.zeros(()))

    def _forward(self, blur, heat):
        return [
            self.image[None].expand_as(blur[:, :, : self.image.shape[1], : self.image.shape[2]])
        ]


@pytest.mark.filterwarnings("ignore:divide by zero")
def test_psnr_ssim_known_values() -> None:
    a = np.random.default_rng(0).random((20, 24, 3))
    assert psnr_ssim(a, a) == (np.inf, 1.0)
    p, _ = psnr_ssim(np.clip(a + 0.01, 0, 1), a)
    mse = np.mean((np.clip(a + 0.01, 0, 1) - a) ** 2)
    assert p == pytest.approx(10 * np.log10(1 / mse))
    _, s = psnr_ssim(a[::-1].copy(), a)
    uniform = structural_similarity(a, a[::-1].copy(), data_range=1, channel_axis=-1)
    assert s < 0.5 and s != pytest.approx(uniform, abs=1e-6)  # Gaussian window, not 7×7


@pytest.mark.filterwarnings("ignore:divide by zero")
def test_evaluate_scores_restored_images(tiny_dataset, tmp_path) -> None:
    ds = DeblurDataset(tiny_dataset, "test", crop=None, augment=False)
    perfect = Oracle(ds.full(0)["sharp"])
    res = evaluate(perfect, ds, out_dir=tmp_path, limit=1)
    assert res.psnr_db == np.inf and res.ssim == pytest.approx(1.0)
    assert res.blur_psnr_db < 40
    rows = list(csv.DictReader((tmp_path / "per_image.csv").open()))
    assert rows[0]["name"] == ds.triplets[0].name
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert "gaussian_weights=True" in summary["conventions"] and summary["count"] == 1
    assert "| oracle |" in summary_table({"oracle": res})


def test_cli_train_then_eval(tiny_dataset, tmp_path, capsys) -> None:
    cfg = {
        "model": {"name": "gamd_only", "preset": "tiny"},
        "data": {"root": str(tiny_dataset), "crop": 16},
        "train": {
            "out_dir": str(tmp_path / "run"),
            "steps": 2,
            "batch_size": 2,
            "tensorboard": True,
            "checkpoint_every": 2,
        },
    }
    (tmp_path / "cfg.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["train", "--config", str(tmp_path / "cfg.yaml"), "--no-progress"]) == 0
    assert "gamd train: gamd_only steps 0->2" in capsys.readouterr().out
    assert any((tmp_path / "run/tensorboard").iterdir())
    ckpt = tmp_path / "run/checkpoints/last.pt"
    assert (
        main(
            [
                "eval",
                "--checkpoint",
                str(ckpt),
                "--data",
                str(tiny_dataset),
                "--out",
                str(tmp_path / "ev"),
                "--no-progress",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "gamd_only@2" in out and "structural_similarity" in out
    assert json.loads((tmp_path / "ev/summary.json").read_text())["count"] == 3


def test_cli_errors_are_one_line(tiny_dataset, tmp_path, capsys) -> None:
    assert main(["train", "--config", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gamd train: error: cannot read config") and "\n" not in err
    (tmp_path / "bad.pt").write_bytes(b"\x00garbage")
    assert (
        main(
            [
                "eval",
                "--checkpoint",
                str(tmp_path / "bad.pt"),
                "--data",
                str(tiny_dataset),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "gamd eval: error: cannot read checkpoint" in capsys.readouterr().err


def test_heat_root_swaps_heat_maps(tiny_dataset, tmp_path) -> None:
    other = tmp_path / "perturbed"
    for src in (Path(tiny_dataset) / "test").glob("*/heat/*.npy"):
        dst = other / "test" / src.parent.parent.name / "heat" / src.name
        dst.parent.mkdir(parents=True, exist_ok=True)
        np.save(dst, np.load(src) + 1.0)
    a = DeblurDataset(tiny_dataset, "test", crop=None, augment=False, heat_scale_px=1.0)
    b = DeblurDataset(
        tiny_dataset, "test", crop=None, augment=False, heat_scale_px=1.0, heat_root=other
    )
    assert torch.allclose(b.full(0)["heat"], a.full(0)["heat"] + 1.0)
    assert torch.equal(b.full(0)["blur"], a.full(0)["blur"])
