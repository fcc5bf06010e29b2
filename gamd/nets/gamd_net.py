"""GAMD, the gyro-assisted motion deblurring network (Luan et al.), as DESIGN describes it.

Pyramid levels k = 1, 2, 3 at ``1/2^(k-1)`` of the input resolution (level 1 = full size):

* inputs: at every level the blurred image (3×3 conv) and the heat maps H_e, H_c (10×10 conv,
  even kernel with 'same' padding) at that level's resolution (:func:`heat_pyramid`);
* body (FPN, inputs C1..C3): level 1 encodes its inputs; level k > 1 concatenates a stride-2
  downsampling of level k-1 with its own input features; each level's features pass through
  its Rconv block (``num_res`` residual units) giving Rconv1..Rconv3;
* FFM fusion with the top level (Rconv1, the first level) feeding every level's FFM:
  ``P1 = Rconv1``, ``P2 = FFM(Rconv2, Rconv1)``, ``P3 = FFM((Rconv3, Rconv2), Rconv1)``;
  FFM resizes its inputs to its own level, concatenates, fuses (1×1 then 3×3 conv) and adds
  the level's own Rconv features;
* decoder from P3 upwards (transposed convs, skip from P2, P1); residual RGB heads give the
  outputs at scales 1 (full size) and 3 (1/4 size), the two the paper's loss uses.

The paper gives no channel counts; the ``paper`` preset uses MIMO-UNet's (32/64/128 channels,
8 residual units per block), which the paper compares against; see docs/gamd.md.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import nn

from gamd.nets.base import DeblurNet, check_width
from gamd.nets.blocks import (
    ConvAct,
    Decoder3,
    SameConv,
    downsample,
    heat_pyramid,
    res_stack,
    resize_to,
)


class InputHead(nn.Module):
    """Level input: image via a 3×3 conv, heat maps via a 10×10 conv, concatenated."""

    def __init__(self, channels: int, use_heat: bool, heat_kernel: int, image_kernel: int) -> None:
        super().__init__()
        self.use_heat = use_heat
        c_img = channels // 2 if use_heat else channels
        self.image = ConvAct(3, c_img, image_kernel)
        self.heat = SameConv(6, channels - c_img, heat_kernel) if use_heat else None

    def forward(self, image: torch.Tensor, heat: torch.Tensor | None) -> torch.Tensor:
        feats = self.image(image)
        if self.heat is not None:
            feats = torch.cat([feats, self.heat(heat)], dim=1)
        return feats


class FFM(nn.Module):
    """Feature fusion module: own-level features fused with other levels' features."""

    def __init__(self, in_channels: list[int], out_channels: int) -> None:
        super().__init__()
        self.fuse = nn.Sequential(
            ConvAct(sum(in_channels), out_channels, 1),
            ConvAct(out_channels, out_channels, 3, act=False),
        )

    def forward(self, own: torch.Tensor, *others: torch.Tensor) -> torch.Tensor:
        size = (int(own.shape[-2]), int(own.shape[-1]))
        feats = [own] + [resize_to(o, size) for o in others]
        return own + self.fuse(torch.cat(feats, dim=1))


class Gamd(DeblurNet):
    """GAMD; ``use_heat=False`` gives the paper's "Only Net" ablation (see gamd_only.py)."""

    OUTPUT_SCALES: ClassVar[tuple[int, ...]] = (1, 4)
    PRESETS: ClassVar[dict[str, dict]] = {
        "tiny": {"base_channels": 8, "num_res": 1},
        "paper": {"base_channels": 32, "num_res": 8},
    }

    def __init__(
        self,
        base_channels: int = 32,
        num_res: int = 8,
        heat_kernel: int = 10,
        image_kernel: int = 3,
        use_heat: bool = True,
    ) -> None:
        super().__init__()
        check_width(type(self).__name__, base_channels, num_res)
        self.uses_heat = bool(use_heat)
        c1, c2, c3 = base_channels, 2 * base_channels, 4 * base_channels
        self.heads = nn.ModuleList(
            InputHead(c, self.uses_heat, heat_kernel, image_kernel) for c in (c1, c2, c3)
        )
        self.down2 = ConvAct(c1, c2, 3, stride=2)
        self.down3 = ConvAct(c2, c3, 3, stride=2)
        self.merge2 = ConvAct(2 * c2, c2, 1)
        self.merge3 = ConvAct(2 * c3, c3, 1)
        self.rconv = nn.ModuleList(res_stack(c, num_res) for c in (c1, c2, c3))
        self.ffm2 = FFM([c2, c1], c2)
        self.ffm3 = FFM([c3, c2, c1], c3)
        self.decoder = Decoder3(c1, c2, c3, num_res, mid_output=False)

    def _forward(self, blur: torch.Tensor, heat: torch.Tensor | None) -> list[torch.Tensor]:
        images = [blur, downsample(blur, 2), downsample(blur, 4)]
        heats = heat_pyramid(heat, 3) if heat is not None else [None, None, None]
        c = [head(im, ht) for head, im, ht in zip(self.heads, images, heats, strict=True)]
        r1 = self.rconv[0](c[0])
        r2 = self.rconv[1](self.merge2(torch.cat([self.down2(r1), c[1]], dim=1)))
        r3 = self.rconv[2](self.merge3(torch.cat([self.down3(r2), c[2]], dim=1)))
        p1 = r1
        p2 = self.ffm2(r2, r1)
        p3 = self.ffm3(r3, r2, r1)
        return self.decoder([p1, p2, p3], images)
