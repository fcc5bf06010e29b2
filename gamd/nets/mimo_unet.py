"""MIMO-UNet (Cho et al., "Rethinking coarse-to-fine approach in single image deblurring",
ICCV 2021), written from the paper's description.

Multi-input multi-output U-Net with three scales (1, 1/2, 1/4):

* SCM (shallow convolutional module) extracts features from the downsampled blurred image
  at scales 1/2 and 1/4; FAM (feature attention module) merges them into the encoder:
  ``FAM(x, y) = x + conv3(x ⊙ y)``;
* AFF (asymmetric feature fusion) concatenates all encoder levels resized to scale 1 (or 1/2),
  fuses them by 1×1 then 3×3 convs, and feeds the decoder at that scale;
* the decoder emits a residual RGB image at every scale: outputs at 1, 1/2, 1/4.

``base_channels = 32, num_res = 8`` is the published MIMO-UNet (6.8 M parameters);
``num_res = 20`` would be MIMO-UNet+. ``extra_channels > 0`` adds input channels (MIMO-Pro's
heat maps), concatenated to the image at every scale; the residual still adds to the image.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import nn

from gamd.errors import GamdConfigError
from gamd.nets.base import DeblurNet, check_width
from gamd.nets.blocks import ConvAct, Decoder3, downsample, heat_pyramid, res_stack, resize_to


class SCM(nn.Module):
    """Shallow convolutional module: features of a downsampled input at ``c_out`` channels."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        if c_out - c_in < 1 or c_out < 8:
            raise GamdConfigError(
                f"SCM needs more output ({c_out}) than input ({c_in}) "
                "channels and at least 8 (raise base_channels)"
            )
        self.main = nn.Sequential(
            ConvAct(c_in, c_out // 4, 3),
            ConvAct(c_out // 4, c_out // 2, 1),
            ConvAct(c_out // 2, c_out // 2, 3),
            ConvAct(c_out // 2, c_out - c_in, 1),
        )
        self.conv = ConvAct(c_out, c_out, 1, act=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(torch.cat([x, self.main(x)], dim=1))


class FAM(nn.Module):
    """Feature attention module: ``x + conv3(x * y)``."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.merge = ConvAct(channels, channels, 3, act=False)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return x + self.merge(x * y)


class AFF(nn.Module):
    """Asymmetric feature fusion of the three encoder levels at one scale."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv = nn.Sequential(ConvAct(c_in, c_out, 1), ConvAct(c_out, c_out, 3, act=False))

    def forward(self, *feats: torch.Tensor) -> torch.Tensor:
        return self.conv(torch.cat(feats, dim=1))


class MimoUNet(DeblurNet):
    """MIMO-UNet; outputs at scales 1, 2 and 4 (finest first)."""

    OUTPUT_SCALES: ClassVar[tuple[int, ...]] = (1, 2, 4)
    PRESETS: ClassVar[dict[str, dict]] = {
        "tiny": {"base_channels": 8, "num_res": 1},
        "paper": {"base_channels": 32, "num_res": 8},
    }

    def __init__(self, base_channels: int = 32, num_res: int = 8, extra_channels: int = 0) -> None:
        super().__init__()
        check_width(type(self).__name__, base_channels, num_res, minimum=8)
        if extra_channels not in (0, 6):
            raise GamdConfigError(
                f"extra_channels must be 0 or 6 (heat maps), got {extra_channels!r}"
            )
        self.uses_heat = extra_channels > 0
        c_in = 3 + extra_channels
        c1, c2, c3 = base_channels, 2 * base_channels, 4 * base_channels
        self.feat_in = ConvAct(c_in, c1, 3)
        self.enc1 = res_stack(c1, num_res)
        self.down2 = ConvAct(c1, c2, 3, stride=2)
        self.scm2 = SCM(c_in, c2)
        self.fam2 = FAM(c2)
        self.enc2 = res_stack(c2, num_res)
        self.down3 = ConvAct(c2, c3, 3, stride=2)
        self.scm3 = SCM(c_in, c3)
        self.fam3 = FAM(c3)
        self.enc3 = res_stack(c3, num_res)
        self.aff1 = AFF(c1 + c2 + c3, c1)
        self.aff2 = AFF(c1 + c2 + c3, c2)
        self.decoder = Decoder3(c1, c2, c3, num_res, mid_output=True)

    def _forward(self, blur: torch.Tensor, heat: torch.Tensor | None) -> list[torch.Tensor]:
        images = [blur, downsample(blur, 2), downsample(blur, 4)]
        if heat is not None:
            inputs = [
                torch.cat([im, ht], dim=1)
                for im, ht in zip(images, heat_pyramid(heat, 3), strict=True)
            ]
        else:
            inputs = images
        e1 = self.enc1(self.feat_in(inputs[0]))
        e2 = self.enc2(self.fam2(self.down2(e1), self.scm2(inputs[1])))
        e3 = self.enc3(self.fam3(self.down3(e2), self.scm3(inputs[2])))
        s1, s2 = e1.shape[-2:], e2.shape[-2:]
        a1 = self.aff1(e1, resize_to(e2, s1), resize_to(e3, s1))
        a2 = self.aff2(resize_to(e1, s2), e2, resize_to(e3, s2))
        return self.decoder([a1, a2, e3], images)
