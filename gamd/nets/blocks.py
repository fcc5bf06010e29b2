"""Building blocks shared by the deblurring networks.

Tensors are ``(B, C, H, W)`` float32. Images are RGB in [0, 1]; heat maps are the DESIGN layout
(6 channels, pixels) divided by the normalisation scale (see :mod:`gamd.heat`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F  # noqa: N812 (the usual alias)
from torch import nn


class ConvAct(nn.Sequential):
    """``Conv2d`` ('same' padding, odd kernel) optionally followed by ReLU."""

    def __init__(
        self, c_in: int, c_out: int, kernel: int = 3, stride: int = 1, act: bool = True
    ) -> None:
        layers: list[nn.Module] = [
            nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=kernel // 2)
        ]
        if act:
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class SameConv(nn.Module):
    """Stride-1 convolution with 'same' output size for any kernel, even ones (10×10).

    An even kernel has no centre; the input is padded by ``(k-1)//2`` before and ``k//2``
    after in each axis (zeros), so the output keeps the input's ``H × W``.
    """

    def __init__(self, c_in: int, c_out: int, kernel: int, act: bool = True) -> None:
        super().__init__()
        self.pad = ((kernel - 1) // 2, kernel // 2, (kernel - 1) // 2, kernel // 2)
        self.conv = nn.Conv2d(c_in, c_out, kernel)
        self.act = nn.ReLU(inplace=True) if act else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.conv(F.pad(x, self.pad)))


class ResBlock(nn.Module):
    """Residual block ``x + conv3(relu(conv3(x)))`` (the paper's Rconv unit, MIMO-UNet's
    ResBlock)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            ConvAct(channels, channels, 3), ConvAct(channels, channels, 3, act=False)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def res_stack(channels: int, num_res: int) -> nn.Sequential:
    """``num_res`` residual blocks in sequence (identity when ``num_res == 0``)."""
    return nn.Sequential(*[ResBlock(channels) for _ in range(num_res)])


def resize_to(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Bilinear resize of ``(B, C, H, W)`` to ``size = (H', W')`` (no-op if equal)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


def downsample(x: torch.Tensor, factor: int) -> torch.Tensor:
    """Bilinear downsampling by an integer factor (the pyramid's image and target scales)."""
    if factor == 1:
        return x
    return F.interpolate(
        x, scale_factor=1.0 / factor, mode="bilinear", align_corners=False, antialias=False
    )


def heat_pyramid(heat: torch.Tensor, levels: int) -> list[torch.Tensor]:
    """Heat maps at pyramid levels ``1 .. levels`` (level k at ``1/2^(k-1)`` resolution).

    Values are displacements in (normalised) pixels of their own resolution, so level k is
    both resized and divided by ``2^(k-1)``.
    """
    return [downsample(heat, 2**k) / (2**k) for k in range(levels)]


def pad_to_multiple(x: torch.Tensor, multiple: int) -> tuple[torch.Tensor, tuple[int, int]]:
    """Replicate-pad the bottom/right of ``x`` so H and W are multiples of ``multiple``.

    Returns the padded tensor and the original ``(H, W)`` for :func:`crop_to`.
    """
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def crop_to(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Inverse of :func:`pad_to_multiple` for a full-resolution output."""
    return x[..., : size[0], : size[1]]


class Decoder3(nn.Module):
    """Three-level U-Net decoder shared by GAMD and MIMO-UNet.

    From the coarsest features upwards: residual stack, 4×4 transposed conv (×2), 1×1 merge
    with the skip features of the next finer level, residual stack; RGB heads add the level's
    input image (residual learning). ``mid_output`` adds the scale-2 head (MIMO-UNet's third
    output; GAMD's loss uses scales 1 and 4 only).
    """

    def __init__(self, c1: int, c2: int, c3: int, num_res: int, mid_output: bool) -> None:
        super().__init__()
        self.dec3 = res_stack(c3, num_res)
        self.out3 = ConvAct(c3, 3, 3, act=False)
        self.up3 = nn.Sequential(
            nn.ConvTranspose2d(c3, c2, 4, stride=2, padding=1), nn.ReLU(inplace=True)
        )
        self.skip2 = ConvAct(2 * c2, c2, 1)
        self.dec2 = res_stack(c2, num_res)
        self.out2 = ConvAct(c2, 3, 3, act=False) if mid_output else None
        self.up2 = nn.Sequential(
            nn.ConvTranspose2d(c2, c1, 4, stride=2, padding=1), nn.ReLU(inplace=True)
        )
        self.skip1 = ConvAct(2 * c1, c1, 1)
        self.dec1 = res_stack(c1, num_res)
        self.out1 = ConvAct(c1, 3, 3, act=False)

    def forward(self, skips: list[torch.Tensor], images: list[torch.Tensor]) -> list[torch.Tensor]:
        """``skips`` = features of levels 1..3 (finest first), ``images`` = the blurred input
        at the same levels; returns the outputs finest first (scales 1, [2,] 4)."""
        d3 = self.dec3(skips[2])
        out3 = self.out3(d3) + images[2]
        d2 = self.dec2(self.skip2(torch.cat([self.up3(d3), skips[1]], dim=1)))
        d1 = self.dec1(self.skip1(torch.cat([self.up2(d2), skips[0]], dim=1)))
        out1 = self.out1(d1) + images[0]
        if self.out2 is None:
            return [out1, out3]
        return [out1, self.out2(d2) + images[1], out3]
