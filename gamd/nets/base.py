"""Common interface of the four deblurring networks.

Every network maps a blurred RGB batch ``blur (B, 3, H, W)`` in [0, 1] and, if it uses them,
normalised heat maps ``heat (B, 6, H, W)`` to a list of restored images, finest first:
``outputs[i]`` has shape ``(B, 3, ceil(H / s_i), ceil(W / s_i))`` with ``s_i = OUTPUT_SCALES[i]``.
Any ``H × W`` works: the input is padded (replicate) to a multiple of ``PAD_MULTIPLE`` and every
output is cropped back.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch
from torch import nn

from gamd.errors import GamdConfigError, GamdDataError
from gamd.nets.blocks import pad_to_multiple


class DeblurNet(nn.Module):
    """Base class: input checks, pad-then-crop, presets."""

    #: Downsampling factor of each output, finest first.
    OUTPUT_SCALES: ClassVar[tuple[int, ...]] = (1,)
    #: H and W are padded to a multiple of this before the forward pass.
    PAD_MULTIPLE: ClassVar[int] = 4
    #: Named constructor arguments: ``tiny`` trains on a CPU, ``paper`` is the published size.
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {}

    uses_heat: bool = False

    def forward(self, blur: torch.Tensor, heat: torch.Tensor | None = None) -> list[torch.Tensor]:
        if blur.ndim != 4 or blur.shape[1] != 3:
            raise GamdDataError(f"blur must be (B, 3, H, W), got {tuple(blur.shape)}")
        if self.uses_heat:
            if heat is None:
                raise GamdDataError(f"{type(self).__name__} needs heat maps")
            if (
                heat.shape[0] != blur.shape[0]
                or heat.shape[1] != 6
                or heat.shape[-2:] != blur.shape[-2:]
            ):
                raise GamdDataError(
                    f"heat maps must be (B, 6, H, W) matching blur {tuple(blur.shape)}, "
                    f"got {tuple(heat.shape)}"
                )
        h, w = blur.shape[-2:]
        blur_p, _ = pad_to_multiple(blur, self.PAD_MULTIPLE)
        heat_p = (
            pad_to_multiple(heat, self.PAD_MULTIPLE)[0]
            if self.uses_heat and heat is not None  # checked above: uses_heat has heat
            else None
        )
        outs = self._forward(blur_p, heat_p)
        return [
            o[..., : math.ceil(h / s), : math.ceil(w / s)]
            for o, s in zip(outs, self.OUTPUT_SCALES, strict=True)
        ]

    def _forward(self, blur: torch.Tensor, heat: torch.Tensor | None) -> list[torch.Tensor]:
        raise NotImplementedError

    @classmethod
    def preset_kwargs(cls, preset: str) -> dict[str, Any]:
        """Constructor arguments of a named preset."""
        if preset not in cls.PRESETS:
            raise GamdConfigError(
                f"{cls.__name__}: unknown preset {preset!r} (known: {sorted(cls.PRESETS)})"
            )
        return dict(cls.PRESETS[preset])


def check_width(name: str, base_channels: int, num_res: int, minimum: int = 4) -> None:
    """Validate the common width/depth arguments."""
    if not isinstance(base_channels, int) or base_channels < minimum:
        raise GamdConfigError(
            f"{name}: base_channels must be an int >= {minimum}, got {base_channels!r}"
        )
    if not isinstance(num_res, int) or num_res < 0:
        raise GamdConfigError(f"{name}: num_res must be an int >= 0, got {num_res!r}")
