"""The four deblurring networks and a registry that builds them by name.

>>> net = build_model("gamd", preset="tiny")
>>> net.uses_heat, net.OUTPUT_SCALES
(True, (1, 4))
"""

from __future__ import annotations

from typing import Any

from gamd.errors import GamdConfigError
from gamd.nets.base import DeblurNet
from gamd.nets.gamd_net import Gamd
from gamd.nets.gamd_only import GamdOnly
from gamd.nets.mimo_pro import MimoPro
from gamd.nets.mimo_unet import MimoUNet

#: Registry name -> class. Names are the ``model.name`` key of the YAML configs.
NETWORKS: dict[str, type[DeblurNet]] = {
    "gamd": Gamd,
    "gamd_only": GamdOnly,
    "mimo_unet": MimoUNet,
    "mimo_pro": MimoPro,
}


def model_kwargs(name: str, preset: str | None = None, **overrides: Any) -> dict[str, Any]:
    """Constructor arguments of ``name``: the preset's, updated by ``overrides``."""
    if name not in NETWORKS:
        raise GamdConfigError(f"unknown network {name!r} (known: {sorted(NETWORKS)})")
    kwargs = NETWORKS[name].preset_kwargs(preset) if preset else {}
    kwargs.update(overrides)
    return kwargs


def build_model(name: str, preset: str | None = None, **overrides: Any) -> DeblurNet:
    """Instantiate a network from its registry name, an optional preset and overrides."""
    kwargs = model_kwargs(name, preset, **overrides)
    try:
        return NETWORKS[name](**kwargs)
    except TypeError as exc:
        raise GamdConfigError(f"{name}: bad constructor arguments {kwargs}: {exc}") from exc


__all__ = [
    "NETWORKS",
    "DeblurNet",
    "Gamd",
    "GamdOnly",
    "MimoPro",
    "MimoUNet",
    "build_model",
    "model_kwargs",
]
