"""Parameter and multiply-accumulate (MAC) counts of a network.

Counted by hand with forward hooks rather than with a counter package: the networks only use
Conv2d, ConvTranspose2d and Linear layers for their arithmetic, three formulas cover them, and
no extra dependency is needed. Element-wise operations (ReLU, additions, bilinear resizing)
are not counted, as is customary for MAC figures in deblurring papers.
"""

from __future__ import annotations

import torch
from torch import nn


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def _layer_macs(module: nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> int:
    if isinstance(module, nn.ConvTranspose2d):
        # every input element is multiplied into (C_out / groups) · kh · kw outputs
        kh, kw = module.kernel_size
        return inputs[0].numel() * (module.out_channels // module.groups) * kh * kw
    if isinstance(module, nn.Conv2d):
        kh, kw = module.kernel_size
        return output.numel() * (module.in_channels // module.groups) * kh * kw
    if isinstance(module, nn.Linear):
        return output.numel() * module.in_features
    return 0


def count_macs(model: nn.Module, *inputs: torch.Tensor | None) -> int:
    """MACs of one forward pass of ``model(*inputs)`` (batch included)."""
    total = 0

    def hook(module: nn.Module, args: tuple[torch.Tensor, ...], output: torch.Tensor) -> None:
        nonlocal total
        total += _layer_macs(module, args, output)

    handles = [
        m.register_forward_hook(hook)
        for m in model.modules()
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear))
    ]
    try:
        with torch.inference_mode():
            model(*inputs)
    finally:
        for h in handles:
            h.remove()
    return total


def macs_for_size(model: nn.Module, height: int, width: int) -> int:
    """MACs of one ``(1, 3, H, W)`` forward pass (with 6-channel heat maps if used).

    Runs a copy of the network on PyTorch's ``meta`` device: shapes propagate, nothing is
    computed, so even 1280 × 720 with the paper's sizes costs milliseconds.
    """
    import copy

    meta = copy.deepcopy(model).to("meta")
    blur = torch.empty(1, 3, height, width, device="meta")
    heat = torch.empty(1, 6, height, width, device="meta")
    return count_macs(meta, blur, heat)
