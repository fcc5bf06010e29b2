"""The benchmark's bookkeeping: dataset assembly from synth outputs, gains and ratios."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from blurtrack.testing.bench_script import load_bench_script
from gamd.data import DeblurDataset


@pytest.fixture(scope="module")
def bench():
    return load_bench_script("bench_gamd")


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


def _fake_session(omega_radps: np.ndarray, readout_s: float):
    """What ``bench/heat_vs_forward.compare`` reads of a session: one 20 ms frame, a gyro."""
    from types import SimpleNamespace

    import pandas as pd

    from blurtrack.geometry.calibration import Calibration
    from blurtrack.geometry.camera import Camera
    from blurtrack.geometry.gyro import GyroTrace

    t = np.linspace(0.0, 0.2, 201)
    gyro = GyroTrace(t, np.tile(omega_radps, (t.size, 1)))
    frames = pd.DataFrame({"timestamp_ns": [50_000_000], "exposure_ns": [20_000_000]})
    session = SimpleNamespace(
        frames=frames,
        frame_times_s=np.array([0.05]),
        exposures_s=np.array([0.02]),
        gyro=lambda: gyro,
    )
    cal = Calibration(Camera((320, 240), (300.0, 300.0, 159.5, 119.5), readout_s=readout_s))
    return session, cal


def test_heat_maps_are_not_forward_displacements() -> None:
    hvf = load_bench_script("heat_vs_forward")
    w = np.array([0.3, 1.5, 0.2])  # rad/s: ~9 px of blur in 20 ms at f = 300 px
    res = {k: hvf.compare(*_fake_session(k * w, 0.0), stride=8)["all"] for k in (1.0, 0.5)}
    blur = res[1.0]["d"]["median"]
    assert 8 < blur < 12
    # Opposite sign to first order: q(1) - q(0) taken as f is off by twice the blur ...
    assert res[1.0]["diff"]["median"] == pytest.approx(2 * blur, rel=0.02)
    # ... and the sign-corrected difference is second order: a fraction of a pixel here, and
    # about a quarter of it at half the rotation.
    small, half = res[1.0]["sum"]["median"], res[0.5]["sum"]["median"]
    assert 0.005 * blur < small < 0.05 * blur
    assert 2.5 < small / half < 5.5
    # Rolling shutter: the row that stops exposing at the reference time has d = -f exactly
    # (row 60 of 240 with a 40 ms readout); the last row, exposing later, differs by far more.
    from blurtrack.geometry.blur_model import BlurModel

    session, cal = _fake_session(w, 0.04)
    model = BlurModel(cal, session.gyro())
    t, e = 0.05, 0.02
    heat, _ = model.heat_maps(t, e, 16, None, 1)
    assert model.default_reference_time(t, e) == pytest.approx(t + 0.04 * 60 / 240 + e, abs=1e-4)
    gap = {}
    for row in (60, 239):
        px = np.stack([np.arange(0, 320, 16.0), np.full(20, float(row))], axis=1)
        t0 = model.camera.row_start_s(t, px[:, 1])
        f = model.warp(px, t0, t0 + e) - px
        d = (heat[2:4] - heat[0:2])[:, row, ::16].T
        gap[row] = float(np.median(np.hypot(*(d + f).T)))
    assert gap[60] < 0.01 < 0.1 < gap[239]
