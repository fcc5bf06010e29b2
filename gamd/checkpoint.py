"""Checkpoints: model, optimiser, scheduler, step, RNG states and the run's config.

Files are written atomically (temporary file, then rename) and read with
``torch.load(weights_only=True)``, so a checkpoint cannot run code. The config travels with
the weights: inference rebuilds the same network and uses the same heat-map normalisation.
"""

from __future__ import annotations

import pickle
import zipfile
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
    import io

    path = Path(path)
    buf = io.BytesIO()  # torch's own file writer turns a full disk into a RuntimeError
    torch.save({"format": FORMAT, **state}, buf)
    atomic.write_bytes_atomic(path, buf.getvalue())
    return path


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint safely and check its format and required keys."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch words every failure of a weights-only load alike; only a real (zip) PyTorch
        # file can hold the disallowed objects, anything else is simply not a checkpoint
        if "weights only" not in str(exc).lower() or not zipfile.is_zipfile(path):
            raise CheckpointError(
                f"cannot read checkpoint {path}: not a readable PyTorch file"
            ) from None
        # torch's message suggests loading unsafely; a checkpoint here never needs that
        raise CheckpointError(
            f"refusing checkpoint {path}: it holds objects other than tensors and plain "
            "containers (checkpoints are only read weights-only)"
        ) from None
    except Exception as exc:  # torch raises many types on corrupt files
        raise CheckpointError(
            f"cannot read checkpoint {path}: not a readable PyTorch file ({type(exc).__name__})"
        ) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} file")
    for key in ("config", "model", "step"):
        if key not in state:
            raise CheckpointError(f"{path}: missing {key!r}")
    check_fields(path, state)
    return state


def check_fields(path: Path, state: dict[str, Any]) -> None:
    """Types and ranges of a checkpoint's fields: one-line errors, never a traceback later."""
    step = state["step"]
    if isinstance(step, bool) or not isinstance(step, int) or not 0 <= step < 10**12:
        raise CheckpointError(f"{path}: 'step' must be an int >= 0, got {step!r}"[:200])
    if not isinstance(state["config"], dict):
        raise CheckpointError(f"{path}: 'config' must be a mapping")
    weights = state["model"]
    if not isinstance(weights, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in weights.items()
    ):
        raise CheckpointError(f"{path}: 'model' must map parameter names to tensors")
    for name, tensor in weights.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise CheckpointError(f"{path}: weight {name!r} holds NaN or inf")
    rng = state.get("rng_cpu")
    if rng is not None and not (isinstance(rng, torch.Tensor) and rng.dtype == torch.uint8):
        raise CheckpointError(f"{path}: 'rng_cpu' must be a uint8 tensor")
    for key in ("optimizer", "scheduler"):
        if key in state and not isinstance(state[key], dict):
            raise CheckpointError(f"{path}: {key!r} must be a mapping")


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
    except (RuntimeError, KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(
            f"{path}: weights do not fit {config.model.name}: {str(exc).splitlines()[0]}"
        ) from exc
    model.eval()
    return model, config, int(state["step"])


def export_weights(src: str | Path, dst: str | Path, data_overrides: dict | None = None) -> Path:
    """A shippable copy of checkpoint ``src``: config, weights and step only (no optimiser,
    scheduler or RNG state), float32, written atomically to ``dst``. ``data_overrides``
    replace keys of the config's ``data`` section (inference-only ones such as ``ensemble``);
    the result must still be a valid config."""
    state = load_checkpoint(src)
    if data_overrides:
        config = dict(state["config"])
        config["data"] = {**config["data"], **data_overrides}
        RunConfig.from_dict(config)  # refuse an override that makes the config invalid
        state["config"] = config
    weights = {
        k: v.detach().float().contiguous() if v.is_floating_point() else v.contiguous()
        for k, v in state["model"].items()
    }
    return save_checkpoint(
        dst, {"config": state["config"], "model": weights, "step": state["step"]}
    )
