"""The deblurring end of ``make demo``: a short GAMD training run and a before/after picture.

:func:`demo_train` trains the tiny GAMD for a few steps on a dataset in ``blurtrack synth``'s
layout (the demo synthesises one first), restores the first test image and writes
``OUT/before_after.png`` (blurred | restored | sharp) plus ``OUT/summary.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

from gamd.config import RunConfig
from gamd.data import DeblurDataset
from gamd.evaluate import psnr_ssim, restore
from gamd.infer import side_by_side, write_rgb
from gamd.train import train


def demo_train(
    dataset: str | Path,
    out_dir: str | Path,
    steps: int = 100,
    crop: int = 64,
    batch_size: int = 4,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = True,
) -> dict:
    """Train tiny GAMD for ``steps`` steps and write the before/after picture; returns the
    summary (PSNR/SSIM of the blurred and the restored test image)."""
    out = Path(out_dir)
    config = RunConfig.from_dict(
        {
            "model": {"name": "gamd", "preset": "tiny"},
            "data": {"root": str(dataset), "crop": crop},
            "train": {
                "out_dir": str(out / "run"),
                "steps": steps,
                "batch_size": batch_size,
                "lr": 1e-3,
                "milestones": [max(1, 3 * steps // 4)],
                "seed": seed,
                "threads": threads,
                "checkpoint_every": steps,
                "progress": progress,
                "tensorboard": False,
            },
        }
    )
    res = train(config, resume="auto")
    split = "test" if (Path(dataset) / "test").is_dir() else "train"  # tiny demo sets
    test = DeblurDataset(
        dataset, split, crop=None, augment=False, heat_scale_px=config.data.heat_scale_px
    )
    item = test.full(0)
    restored = restore(res.model, item["blur"], item["heat"]).permute(1, 2, 0).numpy()
    blur = item["blur"].permute(1, 2, 0).numpy()
    sharp = item["sharp"].permute(1, 2, 0).numpy()
    picture = out / "before_after.png"
    write_rgb(picture, side_by_side(blur, restored, sharp))
    (bp, bs), (rp, rs) = psnr_ssim(blur, sharp), psnr_ssim(restored, sharp)
    summary = {
        "image": f"{split}/{test.triplets[0].name}",
        "steps": steps,
        "picture": str(picture),
        "blurred_psnr_db": bp,
        "blurred_ssim": bs,
        "restored_psnr_db": rp,
        "restored_ssim": rs,
        "checkpoint": str(res.checkpoint),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
