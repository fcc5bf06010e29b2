"""Self-ensemble (flips and quarter turns with consistent heat maps) and the cosine schedule."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from gamd.config import RunConfig
from gamd.errors import GamdConfigError
from gamd.nets import build_model
from gamd.restorer import (
    ENSEMBLE_TRANSFORMS,
    RestoreOptions,
    ensemble_forward,
    restore_image,
)


class _ReadsQ0x(torch.nn.Module):
    """Output = image + 0.01 · q(0)_x: odd under a horizontal flip, even under a vertical one."""

    uses_heat = True

    def forward(self, x: torch.Tensor, heat: torch.Tensor | None) -> list[torch.Tensor]:
        assert heat is not None
        return [x + 0.01 * heat[:, 0:1]]


class _ReadsLength(torch.nn.Module):
    """Output = image + 0.01 · |q(1) − q(0)|: equivariant under every flip and turn."""

    uses_heat = True

    def forward(self, x: torch.Tensor, heat: torch.Tensor | None) -> list[torch.Tensor]:
        assert heat is not None
        d = heat[:, 2:4] - heat[:, 0:2]
        return [x + 0.01 * torch.hypot(d[:, 0:1], d[:, 1:2])]


def _inputs(h: int = 12, w: int = 16) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return torch.rand(1, 3, h, w, generator=g), torch.randn(1, 6, h, w, generator=g)


def test_heat_maps_transform_with_the_image_in_the_ensemble() -> None:
    """A horizontal flip negates x displacements: averaging identity and hflip cancels a
    response to q(0)_x exactly; a vertical flip leaves it (even in x), so 4 = 2 members."""
    x, heat = _inputs()
    net = _ReadsQ0x()
    assert not torch.allclose(ensemble_forward(net, x, heat, 1), x)  # control: it responds
    assert torch.allclose(ensemble_forward(net, x, heat, 2), x, atol=1e-7)
    assert torch.allclose(ensemble_forward(net, x, heat, 4), x, atol=1e-7)


@pytest.mark.parametrize("n", [2, 4, 8])
def test_equivariant_network_is_unchanged_by_the_ensemble(n: int) -> None:
    x, heat = _inputs()
    net = _ReadsLength()
    assert torch.allclose(ensemble_forward(net, x, heat, n), net(x, heat)[0], atol=1e-6)


def test_ensemble_is_the_mean_of_the_undone_transforms_of_a_real_network() -> None:
    """Random GAMD (not equivariant): ensemble 8 = mean of the 8 outputs mapped back, computed
    here independently with numpy-style flips; it differs from the plain output."""
    torch.manual_seed(0)
    net = build_model("gamd", "tiny").eval()
    x, heat = _inputs(16, 16)
    outs = []
    with torch.no_grad():
        for fh, fv, k in ENSEMBLE_TRANSFORMS:
            xt, ht = x.clone(), heat.clone()
            if fh:
                xt, ht = xt.flip(-1), ht.flip(-1)
                ht[:, 0::2] *= -1
            if fv:
                xt, ht = xt.flip(-2), ht.flip(-2)
                ht[:, 1::2] *= -1
            if k:
                xt, ht = torch.rot90(xt, 1, (-2, -1)), torch.rot90(ht, 1, (-2, -1))
                ht = torch.stack([ht[:, 1], -ht[:, 0], ht[:, 3], -ht[:, 2], ht[:, 5], -ht[:, 4]], 1)
            y = net(xt, ht)[0]
            y = torch.rot90(y, -k, (-2, -1)) if k else y
            y = y.flip(-2) if fv else y
            outs.append(y.flip(-1) if fh else y)
        want = torch.stack(outs).mean(0)
        got = ensemble_forward(net, x, heat, 8)
        plain = net(x, heat)[0]
    assert torch.allclose(got, want, atol=1e-6)
    assert (got - plain).abs().max() > 1e-4


def test_gate_still_returns_near_still_input_exactly_with_the_ensemble() -> None:
    torch.manual_seed(0)
    net = build_model("gamd", "tiny").eval()
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(5.0).add_(0.1)
    blur = torch.rand(3, 40, 56)
    still = torch.zeros(6, 40, 56)
    still[0], still[2] = -0.02, 0.02
    opts = RestoreOptions(heat_scale_px=8.0, work_blur_px=8.0, gate_px=(0.3, 1.0), ensemble=8)
    assert torch.equal(restore_image(net, blur, still, opts), blur)
    moving = still.clone()
    moving[0], moving[2] = -5.0, 5.0
    assert (restore_image(net, blur, moving, opts) - blur).abs().mean() > 1e-3


@pytest.mark.parametrize("bad", [0, 3, 16, True, 2.0])
def test_bad_ensemble_size_is_refused(bad: object) -> None:
    with pytest.raises(GamdConfigError, match="ensemble"):
        RestoreOptions(heat_scale_px=8.0, ensemble=bad)  # type: ignore[arg-type]
    with pytest.raises(GamdConfigError, match="ensemble"):
        RunConfig.from_dict(
            {
                "model": {"name": "gamd"},
                "data": {"root": "d", "ensemble": bad},
                "train": {"out_dir": "o"},
            }
        )


def test_ensemble_reaches_the_restore_options_from_the_config() -> None:
    base = {"model": {"name": "gamd"}, "train": {"out_dir": "o"}}
    assert RunConfig.from_dict({**base, "data": {"root": "d"}}).data.restore_options().ensemble == 1
    cfg = RunConfig.from_dict({**base, "data": {"root": "d", "ensemble": 4}})
    assert cfg.data.restore_options().ensemble == 4


def _lrs(config: RunConfig, steps: int) -> list[float]:
    from gamd.train import build_scheduler

    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=config.train.lr)
    sched = build_scheduler(opt, config.train)
    out = []
    for _ in range(steps):
        out.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    return out


def test_cosine_schedule_runs_from_lr_to_lr_min() -> None:
    import math

    cfg = RunConfig.from_dict(
        {
            "model": {"name": "gamd"},
            "data": {"root": "d"},
            "train": {
                "out_dir": "o",
                "steps": 100,
                "lr": 1e-3,
                "schedule": "cosine",
                "lr_min": 1e-5,
            },
        }
    )
    lrs = _lrs(cfg, 100)
    want = [1e-5 + (1e-3 - 1e-5) * (1 + math.cos(math.pi * s / 100)) / 2 for s in range(100)]
    assert lrs == pytest.approx(want, rel=1e-6)
    assert all(a > b for a, b in itertools.pairwise(lrs))
    step = RunConfig.from_dict(
        {
            "model": {"name": "gamd"},
            "data": {"root": "d"},
            "train": {"out_dir": "o", "steps": 100, "lr": 1e-3, "milestones": [50]},
        }
    )
    assert _lrs(step, 100)[49:51] == pytest.approx([1e-3, 5e-4])  # control: step schedule


@pytest.mark.parametrize(
    "train",
    [
        {"schedule": "linear"},
        {"schedule": "cosine", "milestones": [10]},
        {"schedule": "cosine", "lr": 1e-3, "lr_min": 1e-3},
        {"lr_min": -1.0},
    ],
)
def test_bad_schedule_is_refused(train: dict) -> None:
    with pytest.raises(GamdConfigError, match="schedule|milestones|lr_min"):
        RunConfig.from_dict(
            {"model": {"name": "gamd"}, "data": {"root": "d"}, "train": {"out_dir": "o", **train}}
        )


def test_evaluate_scores_the_output_against_the_input(make_dataset, tmp_path) -> None:
    """``vs_input_psnr_db``: inf where the gate returns the input (still heat maps), finite
    where the network acted (the fixture's 2-6 px blur), also with the ensemble."""
    import numpy as np

    from gamd.data import DeblurDataset
    from gamd.evaluate import evaluate, psnr_vs

    a = np.zeros((4, 4, 3))
    assert psnr_vs(a, a) == float("inf") and psnr_vs(a + 0.1, a) == pytest.approx(20.0)
    root = make_dataset(tmp_path / "ds", {"test": 2})
    torch.manual_seed(0)
    net = build_model("gamd", "tiny").eval()
    ds = DeblurDataset(root, "test", crop=None, augment=False, heat_scale_px=8.0)
    opts = RestoreOptions(heat_scale_px=8.0, gate_px=(0.3, 1.0), ensemble=4)
    moving = evaluate(net, ds, options=opts).rows
    assert all(math.isfinite(r["vs_input_psnr_db"]) for r in moving)
    for heat in root.glob("test/*/heat/*.npy"):
        np.save(heat, np.load(heat) * 0.01)  # 0.02-0.06 px: the gate closes
    still = evaluate(net, ds, options=opts).rows
    assert all(r["vs_input_psnr_db"] == math.inf and r["bin"] == "near-still" for r in still)


def _bench_module():
    from blurtrack.testing.bench_script import load_bench_script

    return load_bench_script("gamd_shipped")


def test_near_still_stats_judge_output_against_input() -> None:
    mod = _bench_module()

    def row(bin_: str, vs_in: float, p: float, b: float, length: float) -> dict:
        return {
            "bin": bin_,
            "vs_input_psnr_db": vs_in,
            "psnr_db": p,
            "blur_psnr_db": b,
            "blur_length_px": length,
        }

    rows = [
        row("near-still", math.inf, 80.0, 80.0, 0.1),
        row("near-still", 50.0, 49.0, 60.0, 0.4),
        row("near-still", 60.0, 70.0, 70.5, 0.3),
        row("0.5-5", 20.0, 30.0, 25.0, 0.8),  # not near-still: outside the figure
    ]
    s = mod.near_still_stats(rows)
    assert s["count"] == 3 and s["outside_near_still"] == 1 and s["identical_to_input"] == 1
    assert s["min_vs_input_psnr_db"] == 50.0 and s["median_vs_input_psnr_db"] == 60.0
    assert s["min_psnr_gain_db"] == pytest.approx(-11.0) and s["max_blur_length_px"] == 0.4
    assert s["met"] is True
    rows[1]["vs_input_psnr_db"] = 44.9  # one near-still output 44.9 dB from its input: fails
    assert mod.near_still_stats(rows)["met"] is False
    assert mod.near_still_stats(rows[3:]) == {"count": 0, "outside_near_still": 1}
