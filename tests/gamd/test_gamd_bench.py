"""The benchmark's bookkeeping: dataset assembly from synth outputs, gains and ratios."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest

from gamd.data import DeblurDataset

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_gamd", REPO / "bench" / "bench_gamd.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_link_groups_builds_a_readable_dataset(bench, tiny_dataset, tmp_path) -> None:
    n = bench.link_groups(tiny_dataset, tmp_path / "data" / "train", "a")
    assert n == 4  # two groups in each of the fixture's two splits
    ds = DeblurDataset(tmp_path / "data", "train", crop=None, augment=False)
    assert len(ds) == 9
    copy = tmp_path / "copy"
    shutil.copytree(tiny_dataset, copy)
    assert bench.same_blur(tiny_dataset, copy)
    heat = next(copy.glob("*/*/heat/*.npy"))
    np.save(heat, np.load(heat) + 1)
    assert bench.same_blur(tiny_dataset, copy)  # only the heat maps differ
    blur = next(copy.glob("*/*/blur/*.png"))
    blur.write_bytes(blur.read_bytes() + b"x")
    assert not bench.same_blur(tiny_dataset, copy)
    bench.link_groups(copy, tmp_path / "heat" / "train", "a", what="heat")
    swapped = DeblurDataset(
        tmp_path / "data",
        "train",
        crop=None,
        augment=False,
        heat_scale_px=1.0,
        heat_root=tmp_path / "heat",
    )
    assert swapped.triplets[0].heat.parent.parent.parent.parent == tmp_path / "heat"


def test_gains_and_ratios(bench) -> None:
    prof = {"cpu_ms_median": {"256x256": 10.0}, "macs": {"256x256": 100}}
    nets = {
        "gamd": {
            "psnr_db": 30.0,
            "ssim": 0.9,
            "tiny": prof,
            "perturbed": {"timeshift_ms=2": {"psnr_db": 29.0}, "x": "unavailable"},
        },
        "gamd_only": {"psnr_db": 26.0, "ssim": 0.8, "tiny": prof},
        "mimo_unet": {
            "psnr_db": 25.0,
            "ssim": 0.7,
            "tiny": {"cpu_ms_median": {"256x256": 20.0}, "macs": {"256x256": 50}},
        },
    }
    r = bench.ratios(nets, "tiny")
    assert r["gamd"]["psnr_gain_db"] == 5.0 and r["gamd"]["cpu_ms_ratio_256x256"] == 0.5
    assert r["gamd"]["macs_ratio_256x256"] == 2.0
    s = bench.surviving_gain(nets)
    assert s["gamd"]["clean_gain_db"] == 4.0
    assert s["gamd"]["timeshift_ms=2"] == {"gain_db": 3.0, "fraction": 0.75}
    assert "mimo_pro" not in s
    nets["gamd_only"]["psnr_db"] = 29.99  # a gain within the noise has no surviving share
    assert bench.surviving_gain(nets)["gamd"]["timeshift_ms=2"]["fraction"] is None
