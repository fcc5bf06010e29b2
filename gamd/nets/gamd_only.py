"""GAMD without heat maps: the paper's "Only Net" ablation (the image branch alone)."""

from __future__ import annotations

from typing import ClassVar

from gamd.nets.gamd_net import Gamd


class GamdOnly(Gamd):
    """Same body, FFM and decoder as :class:`Gamd`; the 10×10 heat-map branch is removed and
    the 3×3 image branch takes its channels."""

    PRESETS: ClassVar[dict[str, dict]] = {k: dict(v) for k, v in Gamd.PRESETS.items()}

    def __init__(self, base_channels: int = 32, num_res: int = 8, image_kernel: int = 3) -> None:
        super().__init__(
            base_channels=base_channels, num_res=num_res, image_kernel=image_kernel, use_heat=False
        )
