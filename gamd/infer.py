"""Inference on real recordings: deblur every frame of a session with the heat maps that
``blurtrack predict SESSION --calib CALIB --out DIR`` wrote to ``DIR/heat/<timestamp_ns>.npy``.

The heat maps are normalised with the ``heat_scale_px`` stored in the checkpoint, so
inference sees the same scale as training.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import torch

from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.images import write_image
from gamd.checkpoint import load_model
from gamd.data import read_heat, to_tensor
from gamd.errors import GamdDataError
from gamd.evaluate import restore
from gamd.heat import normalise_heat
from gamd.nets import DeblurNet
from gamd.restorer import RestoreOptions


def frame_to_rgb(image: np.ndarray) -> np.ndarray:
    """A session image as stored (uint8/uint16, gray or BGR) -> float32 RGB in [0, 1]."""
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(image.dtype)
    if scale is None:
        raise GamdDataError(f"unsupported frame pixel type {image.dtype}")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    elif image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    else:
        raise GamdDataError(f"unsupported frame shape {image.shape}")
    return image.astype(np.float32) / scale


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    """Write float RGB in [0, 1] as an 8-bit PNG."""
    bgr = cv2.cvtColor((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)
    write_image(path, bgr)


def deblur_array(
    model: DeblurNet,
    rgb: np.ndarray,
    heat_px: np.ndarray | None,
    options: RestoreOptions | float,
) -> np.ndarray:
    """Deblur one ``(H, W, 3)`` RGB image given its ``(6, H, W)`` heat maps in pixels.

    ``options``: the run's restore options (gate, working resolution), or just its heat-map
    scale (px) for a network applied as is.
    """
    if not isinstance(options, RestoreOptions):
        options = RestoreOptions(float(options))
    heat = None
    if model.uses_heat or options.needs_heat:
        if heat_px is None:
            raise GamdDataError("this network needs heat maps")
        heat = normalise_heat(torch.from_numpy(heat_px), options.heat_scale_px)
    out = restore(model, to_tensor(rgb), heat, options)
    return out.permute(1, 2, 0).numpy()


@dataclass(frozen=True)
class DeblurSummary:
    """What :func:`deblur_session` wrote."""

    out_dir: str
    checkpoint: str
    model: str
    frames: list[int] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    heat_scale_px: float = 0.0
    ensemble: int = 1

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)


def deblur_session(
    checkpoint: str | Path,
    session: str | Path,
    heat_dir: str | Path | None,
    out_dir: str | Path,
    limit: int | None = None,
    skip_missing: bool = False,
    ensemble: int | None = None,
) -> DeblurSummary:
    """Deblur the frames of ``session`` into ``out_dir/<timestamp_ns>.png``.

    ``heat_dir`` is ``blurtrack predict``'s output folder (or its ``heat`` subfolder); every
    frame needs its heat map when the network uses them (no silent fallback). ``ensemble``
    overrides the checkpoint's self-ensemble size (:func:`gamd.restorer.ensemble_forward`).
    """
    from blurtrack.io.session import load_session

    if limit is not None and limit < 1:
        raise GamdDataError(f"limit must be a positive number of images, got {limit}")
    model, config, _ = load_model(checkpoint)
    options = config.data.restore_options()
    if ensemble is not None:
        options = replace(options, ensemble=ensemble)
    needs_heat = model.uses_heat or options.needs_heat
    sess = load_session(session)
    heat_root = None
    if heat_dir is not None:
        heat_root = Path(heat_dir)
        if (heat_root / "heat").is_dir():
            heat_root = heat_root / "heat"
        if not heat_root.is_dir():
            raise GamdDataError(f"heat-map folder not found: {heat_root}")
    elif needs_heat:
        raise GamdDataError(
            f"{config.model.name} needs heat maps: pass the folder written by blurtrack predict"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done: list[int] = []
    skipped: list[int] = []
    n = len(sess.frames) if limit is None else min(limit, len(sess.frames))
    for i in range(n):
        ts = int(sess.frames["timestamp_ns"].iloc[i])
        rgb = frame_to_rgb(sess.read_image(i))
        heat = None
        if needs_heat:
            assert heat_root is not None  # needs_heat requires the heat folder above
            path = heat_root / f"{ts}.npy"
            if not path.is_file():
                if skip_missing:
                    skipped.append(ts)
                    continue
                raise GamdDataError(
                    f"no heat map for frame {ts} in {heat_root} (--skip-missing skips such frames)"
                )
            heat = read_heat(path, rgb.shape[:2])
        write_rgb(out / f"{ts}.png", deblur_array(model, rgb, heat, options))
        done.append(ts)
    summary = DeblurSummary(
        out_dir=str(out),
        checkpoint=str(checkpoint),
        model=config.model.name,
        frames=done,
        skipped=skipped,
        heat_scale_px=config.data.heat_scale_px,
        ensemble=options.ensemble,
    )
    write_json_atomic(out / "summary.json", asdict(summary))
    return summary


def side_by_side(
    before: np.ndarray, after: np.ndarray, sharp: np.ndarray | None = None
) -> np.ndarray:
    """Horizontal montage (blurred | restored | sharp) with 4-px white gaps."""
    parts = [before, after] + ([sharp] if sharp is not None else [])
    gap = np.ones((before.shape[0], 4, 3), np.float32)
    row = []
    for p in parts:
        row += [p, gap]
    return np.concatenate(row[:-1], axis=1)
