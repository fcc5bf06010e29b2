"""Weights that ship with the package: ``gamd.pt`` (GAMD) and ``gamd_only.pt`` (its
no-heat-map twin), trained by ``python bench/train_shipped.py`` from ``configs/gamd/shipped_*.yaml``
(docs/gamd.md, "Shipped weights"). Each file is a weights-only checkpoint (config, weights,
step) read with ``torch.load(weights_only=True)``."""

from __future__ import annotations

from pathlib import Path

from gamd.errors import CheckpointError

WEIGHTS_DIR = Path(__file__).resolve().parent
SHIPPED = ("gamd", "gamd_only")


def shipped_weights(name: str = "gamd") -> Path:
    """Path of the shipped weights of network ``name`` (``gamd`` or ``gamd_only``)."""
    if name not in SHIPPED:
        raise CheckpointError(f"no shipped weights for {name!r} (shipped: {list(SHIPPED)})")
    path = WEIGHTS_DIR / f"{name}.pt"
    if not path.is_file():
        raise CheckpointError(f"shipped weights {path} are missing from this installation")
    return path
