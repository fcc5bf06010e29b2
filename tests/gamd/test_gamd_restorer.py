"""Do no harm (gate), the working resolution, and the binned evaluation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from gamd.data import DeblurDataset
from gamd.evaluate import blur_bin, evaluate, gain_stats, psnr_ssim
from gamd.nets import build_model
from gamd.restorer import (
    RestoreOptions,
    blur_length_px,
    gate,
    restore_image,
    to_working,
    working_scale,
)


def _wild_net(name: str = "gamd") -> torch.nn.Module:
    """A network whose output is far from its input (large random weights)."""
    torch.manual_seed(0)
    net = build_model(name, "tiny")
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(5.0).add_(0.1)
    return net.eval()


def _hwc(x: torch.Tensor) -> np.ndarray:
    return x.permute(1, 2, 0).numpy()


def _heat(h: int, w: int, dx: float, dy: float = 0.0) -> torch.Tensor:
    """Straight uniform motion from -d/2 to +d/2 (control point in the middle)."""
    heat = torch.zeros(6, h, w)
    heat[0], heat[1], heat[2], heat[3] = -dx / 2, -dy / 2, dx / 2, dy / 2
    return heat


def test_blur_length_and_gate() -> None:
    heat = _heat(4, 5, 3.0, 4.0)
    assert torch.allclose(blur_length_px(heat), torch.full((1, 4, 5), 5.0))
    g = gate(torch.stack([_heat(2, 2, v) for v in (0.1, 0.65, 2.0)]), (0.3, 1.0))
    assert g[:, 0, 0, 0].tolist() == pytest.approx([0.0, 0.5, 1.0])


@pytest.mark.parametrize("name", ["gamd", "gamd_only"])
@pytest.mark.parametrize("work", [None, 4.0])
def test_do_no_harm_where_heat_maps_show_no_blur(name: str, work: float | None) -> None:
    """Near-still pixels come back unchanged (>= 45 dB; here exactly) whatever the weights,
    also when the rest of the frame is strongly blurred and restored at a working scale."""
    net = _wild_net(name)
    opts = RestoreOptions(heat_scale_px=8.0, work_blur_px=work, gate_px=(0.3, 1.0))
    rng = np.random.default_rng(1)
    blur = torch.from_numpy(rng.random((3, 64, 96), dtype=np.float32))
    still = _heat(64, 96, 0.05)
    out = restore_image(net, blur, still, opts)
    assert torch.equal(out, blur)
    mixed = _heat(64, 96, 20.0)
    mixed[:, :, :40] = still[:, :, :40]  # left part still, right part 20 px of blur
    out = restore_image(net, blur, mixed, opts)
    assert torch.equal(out[:, :, :40], blur[:, :, :40])
    assert (out[:, :, 60:] - blur[:, :, 60:]).abs().mean() > 1e-3  # the network acted there
    with np.errstate(divide="ignore"):
        p, _ = psnr_ssim(_hwc(out[:, :, :40]), _hwc(blur[:, :, :40]))
    assert p == math.inf or p >= 45


def test_without_gate_the_wild_net_does_harm() -> None:
    """Control: the same network without the gate changes a still image a lot."""
    net = _wild_net()
    blur = torch.rand(3, 32, 32)
    out = restore_image(net, blur, _heat(32, 32, 0.05), RestoreOptions(heat_scale_px=8.0))
    assert (out - blur).abs().mean() > 1e-2


def test_working_scale_and_heat_rescaling() -> None:
    heat = _heat(64, 128, 32.0)
    assert working_scale(heat, 8.0) == pytest.approx(4.0)
    assert working_scale(heat, 8.0, max_scale=2.0) == 2.0
    assert working_scale(_heat(8, 8, 1.0), 8.0) == 1.0
    (img,), hs = to_working([torch.rand(1, 3, 64, 128)], heat[None], 4.0)
    assert img.shape[-2:] == (16, 32) and hs.shape == (1, 6, 16, 32)
    assert float(blur_length_px(hs).mean()) == pytest.approx(8.0, rel=1e-5)


def test_dataset_work_resolution_items(tiny_dataset) -> None:
    plain = DeblurDataset(tiny_dataset, "train", crop=16, heat_scale_px=4.0)
    work = DeblurDataset(tiny_dataset, "train", crop=16, heat_scale_px=4.0, work_blur_px=2.0)
    a, b = plain[(0, 3)], work[(0, 3)]
    assert a["blur"].shape == b["blur"].shape == (3, 16, 16)
    la = float(blur_length_px(a["heat"] * 4.0).quantile(0.9))
    lb = float(blur_length_px(b["heat"] * 4.0).quantile(0.9))
    assert lb < la  # the working item's blur is shorter (in its own pixels)


def test_bins_and_gain_stats() -> None:
    assert [blur_bin(v) for v in (0.1, 0.5, 7.0, 25.0, 59.9, 500.0, math.nan)] == [
        "near-still",
        "0.5-5",
        "5-10",
        "20-30",
        "30-60",
        ">=120",
        "unknown",
    ]
    rows = [
        {"psnr_db": p, "blur_psnr_db": b, "ssim": 0.9, "blur_ssim": 0.8, "blur_length_px": 3.0}
        for p, b in ((30.0, 28.0), (25.0, 26.0), (40.0, 30.0))
    ]
    g = gain_stats(rows)
    assert g["median_psnr_gain_db"] == pytest.approx(2.0)
    assert g["mean_psnr_gain_db"] == pytest.approx(11.0 / 3)
    assert g["worse_count"] == 1 and g["median_ssim_gain"] == pytest.approx(0.1)


def test_evaluate_reports_binned_gains(tiny_dataset, tmp_path) -> None:
    net = _wild_net()
    ds = DeblurDataset(tiny_dataset, "test", crop=None, augment=False, heat_scale_px=8.0)
    opts = RestoreOptions(heat_scale_px=8.0, gate_px=(0.3, 1.0))
    res = evaluate(net, ds, out_dir=tmp_path / "ev", options=opts)
    s = res.summary()
    assert sum(b["count"] for b in s["bins"].values()) == len(ds) == s["overall"]["count"]
    assert "median_psnr_gain_db" in s["blurred"]
    for r in res.rows:  # lengths are the manifest's median |q1 - q0|
        assert r["blur_length_px"] > 0 and r["bin"] == blur_bin(r["blur_length_px"])


@pytest.mark.parametrize("net", ["gamd", "gamd_only"])
def test_shipped_weights_load_and_do_no_harm(net: str) -> None:
    from gamd.checkpoint import load_model
    from gamd.weights import shipped_weights

    path = shipped_weights(net)
    assert path.stat().st_size <= 2_000_000
    model, cfg, step = load_model(path)
    assert step > 0 and cfg.model.name == net and cfg.data.gate_px is not None
    blur = torch.rand(3, 48, 64)
    out = restore_image(model, blur, _heat(48, 64, 0.1), cfg.data.restore_options())
    assert torch.equal(out, blur)


def _rolling_shutter_example(h: int = 72, w: int = 96, speed_px: float = 6.0):
    """A rolling-shutter-like triplet: every row blurs along the same straight motion of
    ``speed_px`` but is offset by the motion between its own mid-exposure and the reference
    time (linear in the row, 0 at the centre row): ``B(x) = mean_t S(x + q_x(t))``."""
    from tests.gamd.conftest import bezier_blur

    rng = np.random.default_rng(3)
    noise = rng.random((h // 6 + 2, w // 6 + 2, 3)).astype(np.float32)
    sharp = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1)
    direction = np.array([0.8, 0.6])
    offset = ((np.arange(h) - (h - 1) / 2) / (h - 1) * 1.5 * speed_px)[:, None, None]
    centred = np.zeros((6, h, w), np.float32)
    for k, tau in enumerate((0.0, 1.0, 0.5)):  # q(0), q(1), P of a straight uniform motion
        centred[2 * k : 2 * k + 2] = ((tau - 0.5) * speed_px * direction)[:, None, None]
    heat = centred.copy()
    shift = np.stack([offset[:, :, 0] * direction[0], offset[:, :, 0] * direction[1]])
    heat += np.tile(shift, (3, 1, 1))  # (2, h, 1) -> every point of every row
    return sharp, bezier_blur(sharp, heat), heat, bezier_blur(sharp, centred)


def test_recentre_undoes_the_rolling_shutter_offset() -> None:
    from gamd.restorer import RECENTRE_MIN_PX, centre_offset, recentre

    _, blur, heat, centred_blur = _rolling_shutter_example()
    b = torch.from_numpy(blur).permute(2, 0, 1)[None]
    hp = torch.from_numpy(heat)[None]
    assert float(centre_offset(hp).abs().max()) > 3.5  # rows up to 4.5 px * (0.8, 0.6) off
    (b2,), h2 = recentre([b], hp)
    # The recentred heat maps pass through 0 half-way, keep the blur, and the image is the
    # centred blur of the same sharp image (bilinear resampling error only), far closer to
    # it than the input was (negative control).
    assert float(centre_offset(h2).abs().max()) < 1e-3
    assert torch.allclose(blur_length_px(h2), blur_length_px(hp), atol=1e-3)
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))  # away from the border
    ref = torch.from_numpy(centred_blur).permute(2, 0, 1)[None]
    err_after = float((b2 - ref)[inner].abs().mean())
    err_before = float((b - ref)[inner].abs().mean())
    assert err_after < 0.01 < 0.03 < err_before
    # Centred blur (global shutter) is left exactly as it is.
    small = hp.clone()
    small[:, :] -= centre_offset(hp).repeat(1, 3, 1, 1) - 0.3 * RECENTRE_MIN_PX
    (b3,), h3 = recentre([b], small)
    assert b3 is b and h3 is small


def test_restore_recentres_rolling_shutter() -> None:
    from gamd.restorer import recentre

    _, blur, heat, _ = _rolling_shutter_example()
    b = torch.from_numpy(blur).permute(2, 0, 1)
    hp = torch.from_numpy(heat)
    torch.manual_seed(0)
    net = build_model("gamd", "tiny").eval()  # untrained: about the identity plus a residual
    on = restore_image(net, b, hp, RestoreOptions(heat_scale_px=8.0))
    off = restore_image(net, b, hp, RestoreOptions(heat_scale_px=8.0, recentre=False))
    (b2,), h2 = recentre([b[None]], hp[None])
    want = restore_image(net, b2[0], h2[0], RestoreOptions(heat_scale_px=8.0, recentre=False))
    assert torch.equal(on, want) and not torch.allclose(on, off, atol=1e-3)


def test_training_items_are_recentred_like_inference(make_dataset, tmp_path) -> None:
    from gamd.restorer import centre_offset, recentre

    root = make_dataset(tmp_path / "ds", {"train": 2})  # constant motion, off-centre by design
    for recentred in (True, False):
        ds = DeblurDataset(
            root, "train", crop=None, augment=False, heat_scale_px=4.0, recentre=recentred
        )
        full, item = ds.full(1), ds[(1, 5)]
        hp = full["heat"][None] * 4.0
        assert float(centre_offset(hp).abs().max()) > 0.1
        if recentred:
            (b,), h = recentre([full["blur"][None]], hp)
            assert torch.equal(item["blur"], b[0]) and torch.allclose(item["heat"], h[0] / 4.0)
            assert torch.equal(item["sharp"], full["sharp"])  # the target is the reference
        else:
            assert torch.equal(item["blur"], full["blur"])


def test_recentre_config_is_a_boolean_and_reaches_the_restore_options() -> None:
    from gamd.config import RunConfig
    from gamd.errors import GamdConfigError

    base = {"model": {"name": "gamd"}, "train": {"out_dir": "x"}}
    assert RunConfig.from_dict({**base, "data": {"root": "d"}}).data.restore_options().recentre
    off = RunConfig.from_dict({**base, "data": {"root": "d", "recentre": False}})
    assert off.data.restore_options().recentre is False
    with pytest.raises(GamdConfigError, match="data.recentre must be true or false"):
        RunConfig.from_dict({**base, "data": {"root": "d", "recentre": "no"}})
