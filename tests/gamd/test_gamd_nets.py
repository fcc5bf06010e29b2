"""Networks: shapes at any size, heat usage, presets, parameter and MAC counts."""

from __future__ import annotations

import pytest
import torch

from gamd.errors import GamdConfigError, GamdDataError
from gamd.macs import count_macs, count_parameters
from gamd.nets import NETWORKS, build_model
from gamd.nets.blocks import SameConv, heat_pyramid

NAMES = sorted(NETWORKS)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("hw", [(16, 16), (21, 34), (9, 13)])
def test_any_size_pads_then_crops(name: str, hw: tuple[int, int]) -> None:
    torch.manual_seed(0)
    net = build_model(name, "tiny").eval()
    blur, heat = torch.rand(2, 3, *hw), torch.randn(2, 6, *hw)
    with torch.no_grad():
        outs = net(blur, heat)
    assert len(outs) == len(net.OUTPUT_SCALES)
    for out, s in zip(outs, net.OUTPUT_SCALES, strict=True):
        assert out.shape == (2, 3, -(-hw[0] // s), -(-hw[1] // s))
        assert torch.isfinite(out).all()


@pytest.mark.parametrize("name", NAMES)
def test_heat_maps_matter_only_for_heat_networks(name: str) -> None:
    torch.manual_seed(1)
    net = build_model(name, "tiny").eval()
    blur = torch.rand(1, 3, 16, 16)
    h1, h2 = torch.randn(1, 6, 16, 16), torch.randn(1, 6, 16, 16)
    with torch.no_grad():
        same = torch.equal(net(blur, h1)[0], net(blur, h2)[0])
    assert same == (not net.uses_heat)
    assert net.uses_heat == (name in ("gamd", "mimo_pro"))


def test_missing_or_bad_heat_is_refused() -> None:
    net = build_model("gamd", "tiny")
    with pytest.raises(GamdDataError, match="heat"):
        net(torch.rand(1, 3, 8, 8))
    with pytest.raises(GamdDataError, match="heat"):
        net(torch.rand(1, 3, 8, 8), torch.rand(1, 4, 8, 8))
    with pytest.raises(GamdDataError, match="blur"):
        net(torch.rand(1, 1, 8, 8), torch.rand(1, 6, 8, 8))


def test_presets_and_bad_arguments() -> None:
    with pytest.raises(GamdConfigError, match="preset"):
        build_model("gamd", "huge")
    with pytest.raises(GamdConfigError, match="unknown network"):
        build_model("srn")
    with pytest.raises(GamdConfigError, match="base_channels"):
        build_model("mimo_unet", base_channels=4, num_res=1)
    with pytest.raises(GamdConfigError, match="constructor"):
        build_model("gamd", "tiny", width=3)


def test_mimo_unet_paper_size_matches_published_parameter_count() -> None:
    # Cho et al. report 6.8 M parameters for MIMO-UNet
    n = count_parameters(build_model("mimo_unet", "paper"))
    assert 6.75e6 < n < 6.85e6


def test_even_kernel_same_conv_keeps_size_and_gamd_uses_10x10() -> None:
    conv = SameConv(6, 4, 10)
    assert conv(torch.rand(1, 6, 11, 7)).shape == (1, 4, 11, 7)
    net = build_model("gamd", "tiny")
    kernels = {tuple(m.conv.weight.shape[-2:]) for m in net.modules() if isinstance(m, SameConv)}
    assert kernels == {(10, 10)}


def test_heat_pyramid_rescales_displacements() -> None:
    heat = torch.full((1, 6, 16, 16), 8.0)
    levels = heat_pyramid(heat, 3)
    assert [lv.shape[-1] for lv in levels] == [16, 8, 4]
    assert [float(lv.mean()) for lv in levels] == [8.0, 4.0, 2.0]


def test_mac_counter_known_values() -> None:
    conv = torch.nn.Conv2d(3, 8, 3, padding=1)
    assert count_macs(conv, torch.rand(1, 3, 10, 10)) == 8 * 100 * 3 * 9
    tconv = torch.nn.ConvTranspose2d(4, 2, 4, stride=2, padding=1)
    assert count_macs(tconv, torch.rand(1, 4, 5, 5)) == 4 * 25 * 2 * 16
    lin = torch.nn.Linear(5, 7)
    assert count_macs(lin, torch.rand(3, 5)) == 3 * 7 * 5
    net = build_model("gamd", "tiny")
    small = count_macs(net, torch.rand(1, 3, 32, 32), torch.rand(1, 6, 32, 32))
    big = count_macs(net, torch.rand(1, 3, 64, 64), torch.rand(1, 6, 64, 64))
    assert big == 4 * small


def test_meta_device_macs_and_profile_with_injected_clock() -> None:
    from gamd.macs import macs_for_size
    from gamd.profile import forward_ms, profile

    net = build_model("mimo_unet", "tiny")
    assert macs_for_size(net, 32, 48) == count_macs(net, torch.rand(1, 3, 32, 48))
    ticks = iter(range(100))
    times = forward_ms(net, 8, 8, repeats=2, clock=lambda: float(next(ticks)))
    assert times == [1000.0, 1000.0]
    prof = profile(net, [(16, 24)], time_it=False)
    assert prof["params"] == count_parameters(net) and "24x16" in prof["macs"]
