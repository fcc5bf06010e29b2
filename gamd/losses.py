"""Training losses.

* :func:`gamd_loss` — the paper's ``L = ‖L1 − S1‖/k1 + ω‖L3 − S3‖/k3`` with ω = 0.6. Our
  reading (docs/gamd.md): the norm is the L1 norm, ``k`` the number of elements of that scale
  (so each term is a mean absolute error), "scale 1" the full-resolution output and "scale 3"
  the third pyramid level, i.e. 1/4 resolution; ``S3`` is the sharp image downsampled
  bilinearly by 4.
* :func:`mimo_loss` — MIMO-UNet's own loss: the multi-scale content loss (mean L1 at scales
  1, 1/2, 1/4, summed) plus λ = 0.1 times the multi-scale frequency loss (mean L1 between the
  2-D FFTs, real and imaginary parts, of output and target).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F  # noqa: N812 (the usual alias)

from gamd.errors import GamdConfigError
from gamd.nets.blocks import downsample


def _target(sharp: torch.Tensor, like: torch.Tensor, factor: int) -> torch.Tensor:
    target = downsample(sharp, factor)
    if target.shape != like.shape:
        raise GamdConfigError(
            f"output {tuple(like.shape)} does not match the sharp image at "
            f"scale 1/{factor} {tuple(target.shape)}; use crops divisible by 4"
        )
    return target


def gamd_loss(
    outputs: Sequence[torch.Tensor], sharp: torch.Tensor, scales: Sequence[int], omega: float = 0.6
) -> torch.Tensor:
    """The paper's loss on the outputs at scale factors 1 and 4 (levels 1 and 3)."""
    by_scale = dict(zip(scales, outputs, strict=True))
    if 1 not in by_scale or 4 not in by_scale:
        raise GamdConfigError(f"gamd loss needs outputs at scales 1 and 4, got {list(scales)}")
    l1 = F.l1_loss(by_scale[1], sharp)
    l3 = F.l1_loss(by_scale[4], _target(sharp, by_scale[4], 4))
    return l1 + omega * l3


def mimo_loss(
    outputs: Sequence[torch.Tensor],
    sharp: torch.Tensor,
    scales: Sequence[int],
    fft_weight: float = 0.1,
) -> torch.Tensor:
    """MIMO-UNet's content + 0.1 × frequency loss over all its outputs."""
    content = sharp.new_zeros(())
    freq = sharp.new_zeros(())
    for out, factor in zip(outputs, scales, strict=True):
        target = _target(sharp, out, factor)
        content = content + F.l1_loss(out, target)
        fo = torch.view_as_real(torch.fft.fft2(out))
        ft = torch.view_as_real(torch.fft.fft2(target))
        freq = freq + F.l1_loss(fo, ft)
    return content + fft_weight * freq


LOSSES = {"gamd": gamd_loss, "mimo": mimo_loss}
