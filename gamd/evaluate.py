"""Evaluation: PSNR and SSIM of restored images against the sharp ones.

Conventions (also written into every summary): RGB, float in [0, 1], network outputs clipped
to [0, 1], no 8-bit quantisation of the output; PSNR and SSIM from scikit-image
(``peak_signal_noise_ratio(data_range=1)`` over all three channels;
``structural_similarity(data_range=1, channel_axis=-1, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)``, i.e. Wang et al.'s Gaussian-window SSIM averaged over
channels); full images, no border crop. The input (blurred) image is scored the same way as
the reference point.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity
from tqdm import tqdm

from blurtrack.io.atomic import write_text_atomic
from gamd.data import DeblurDataset
from gamd.nets import DeblurNet

CONVENTIONS = (
    "RGB float in [0,1], outputs clipped, no quantisation; skimage "
    "peak_signal_noise_ratio(data_range=1); skimage structural_similarity("
    "data_range=1, channel_axis=-1, gaussian_weights=True, sigma=1.5, "
    "use_sample_covariance=False); full image, no border crop"
)


def psnr_ssim(pred_hwc: np.ndarray, sharp_hwc: np.ndarray) -> tuple[float, float]:
    """PSNR (dB) and SSIM of two ``(H, W, 3)`` float images in [0, 1].

    >>> a = np.zeros((16, 16, 3)); b = a + 0.1
    >>> round(psnr_ssim(b, a)[0], 6)
    20.0
    """
    psnr = float(peak_signal_noise_ratio(sharp_hwc, pred_hwc, data_range=1.0))
    ssim = float(
        structural_similarity(
            sharp_hwc,
            pred_hwc,
            data_range=1.0,
            channel_axis=-1,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
        )
    )
    return psnr, ssim


@torch.inference_mode()
def restore(model: DeblurNet, blur: torch.Tensor, heat: torch.Tensor | None) -> torch.Tensor:
    """Full-resolution restoration of ``blur (3, H, W)`` (``heat (6, H, W)`` normalised),
    clipped to [0, 1]."""
    device = next(model.parameters()).device
    h = heat[None].to(device) if model.uses_heat and heat is not None else None
    out = model(blur[None].to(device), h)[0][0]
    return out.clamp(0.0, 1.0).cpu()


@dataclass(frozen=True)
class EvalResult:
    """Per-image and mean metrics; ``blur_*`` score the blurred input itself."""

    rows: list[dict] = field(default_factory=list)
    psnr_db: float = math.nan
    ssim: float = math.nan
    blur_psnr_db: float = math.nan
    blur_ssim: float = math.nan
    conventions: str = CONVENTIONS

    def summary(self) -> dict:
        d = asdict(self)
        d.pop("rows")
        d["count"] = len(self.rows)
        return d


def evaluate(
    model: DeblurNet,
    dataset: DeblurDataset,
    out_dir: str | Path | None = None,
    limit: int | None = None,
    progress: bool = False,
) -> EvalResult:
    """Score ``model`` on every image of ``dataset`` (full size); write ``per_image.csv`` and
    ``summary.json`` to ``out_dir`` if given."""
    model.eval()
    rows = []
    count = len(dataset) if limit is None else min(limit, len(dataset))
    for i in tqdm(range(count), disable=not progress, desc="eval", unit="img"):
        item = dataset.full(i)
        pred = restore(model, item["blur"], item["heat"])
        sharp = item["sharp"].permute(1, 2, 0).numpy()
        p, s = psnr_ssim(pred.permute(1, 2, 0).numpy(), sharp)
        bp, bs = psnr_ssim(item["blur"].permute(1, 2, 0).numpy(), sharp)
        rows.append(
            {
                "name": dataset.triplets[i].name,
                "psnr_db": p,
                "ssim": s,
                "blur_psnr_db": bp,
                "blur_ssim": bs,
            }
        )
    means = {
        k: float(np.mean([r[k] for r in rows])) if rows else math.nan
        for k in ("psnr_db", "ssim", "blur_psnr_db", "blur_ssim")
    }
    result = EvalResult(rows=rows, **means)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        with (out / "per_image.csv").open("w", newline="") as f:
            w = csv.DictWriter(
                f, fieldnames=["name", "psnr_db", "ssim", "blur_psnr_db", "blur_ssim"]
            )
            w.writeheader()
            w.writerows(rows)
        write_text_atomic(out / "summary.json", json.dumps(result.summary(), indent=2))
    return result


def summary_table(results: dict[str, EvalResult]) -> str:
    """A Markdown table of mean PSNR/SSIM per model name."""
    lines = [
        "| model | PSNR (dB) | SSIM | input PSNR | input SSIM | images |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r.psnr_db:.2f} | {r.ssim:.4f} | {r.blur_psnr_db:.2f} | "
            f"{r.blur_ssim:.4f} | {len(r.rows)} |"
        )
    return "\n".join(lines)
