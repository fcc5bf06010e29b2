"""Checkpoints: model, optimiser, scheduler, step, RNG states and the run's config.

Files are written atomically (temporary file, then rename) and read with
``torch.load(weights_only=True)``, so a checkpoint cannot run code. The config travels with
the weights: inference rebuilds the same network and uses the same heat-map normalisation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from blurtrack.io import atomic
from gamd.config import RunConfig
from gamd.errors import CheckpointError, GamdError
from gamd.nets import DeblurNet, build_model

FORMAT = "gamd-checkpoint/1"


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (plus the format tag) to ``path`` atomically."""
    path = Path(path)
    with atomic.atomic_path(path) as tmp:
        torch.save({"format": FORMAT, **state}, tmp)
    return path


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint safely and check its format and required keys."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types on corrupt or unsafe files
        raise CheckpointError(f"cannot read checkpoint {path}: {exc}".splitlines()[0]) from exc
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} file")
    for key in ("config", "model", "step"):
        if key not in state:
            raise CheckpointError(f"{path}: missing {key!r}")
    return state


def load_model(path: str | Path) -> tuple[DeblurNet, RunConfig, int]:
    """Network (in eval mode, on CPU), its run config and training step from a checkpoint."""
    state = load_checkpoint(path)
    try:
        config = RunConfig.from_dict(state["config"])
    except GamdError as exc:
        raise CheckpointError(f"{path}: bad embedded config: {exc}") from exc
    model = build_model(config.model.name, config.model.preset, **config.model.kwargs)
    try:
        model.load_state_dict(state["model"])
    except (RuntimeError, KeyError) as exc:
        raise CheckpointError(
            f"{path}: weights do not fit {config.model.name}: {str(exc).splitlines()[0]}"
        ) from exc
    model.eval()
    return model, config, int(state["step"])
