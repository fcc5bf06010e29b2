"""MIMO-Pro: MIMO-UNet with the heat maps (H_e, H_c: 6 channels) as extra input at every
scale, the paper's strongest baseline."""

from __future__ import annotations

from typing import ClassVar

from gamd.nets.mimo_unet import MimoUNet


class MimoPro(MimoUNet):
    """:class:`MimoUNet` whose inputs at scales 1, 1/2, 1/4 are ``[image, heat maps]``."""

    PRESETS: ClassVar[dict[str, dict]] = {k: dict(v) for k, v in MimoUNet.PRESETS.items()}

    def __init__(self, base_channels: int = 32, num_res: int = 8) -> None:
        super().__init__(base_channels=base_channels, num_res=num_res, extra_channels=6)
