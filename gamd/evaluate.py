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
import io
import itertools
import math
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity
from tqdm import tqdm

from blurtrack.io.atomic import write_json_atomic, write_text_atomic
from gamd.data import DeblurDataset
from gamd.errors import GamdError
from gamd.nets import DeblurNet
from gamd.restorer import RestoreOptions, restore_image

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


def psnr_vs(a_hwc: np.ndarray, b_hwc: np.ndarray) -> float:
    """PSNR (dB, data range 1) of ``a`` against ``b``; ``inf`` when they are identical (the
    do-no-harm measure: output against input)."""
    mse = float(np.mean((np.asarray(a_hwc, np.float64) - np.asarray(b_hwc, np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


@torch.inference_mode()
def restore(
    model: DeblurNet,
    blur: torch.Tensor,
    heat: torch.Tensor | None,
    options: RestoreOptions | None = None,
    work: bool = True,
) -> torch.Tensor:
    """Full-resolution restoration of ``blur (3, H, W)``, clipped to [0, 1].

    Without ``options``, ``heat (6, H, W)`` is the network's normalised input and the network
    is applied as is. With ``options`` (the run's :meth:`DataConfig.restore_options`), ``heat``
    is normalised by ``options.heat_scale_px`` and the gate and working resolution of
    :mod:`gamd.restorer` apply.
    """
    if options is not None:
        heat_px = heat * options.heat_scale_px if heat is not None else None
        return restore_image(model, blur, heat_px, options, work=work)
    device = next(model.parameters()).device
    h = heat[None].to(device) if model.uses_heat and heat is not None else None
    out = model(blur[None].to(device), h)[0][0]
    return out.clamp(0.0, 1.0).cpu()


#: Bin edges of the median blur length (px); below the first edge a triplet is "near-still".
BLUR_BINS_PX = (0.5, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0)
METRICS = ("psnr_db", "ssim", "blur_psnr_db", "blur_ssim")


def blur_bin(length_px: float, edges: tuple[float, ...] = BLUR_BINS_PX) -> str:
    """Name of the blur-length bin of a triplet ("near-still", "0.5-5", ..., ">=120",
    "unknown" without heat maps)."""
    if not math.isfinite(length_px):
        return "unknown"
    if length_px < edges[0]:
        return "near-still"
    for lo, hi in itertools.pairwise(edges):
        if length_px < hi:
            return f"{lo:g}-{hi:g}"
    return f">={edges[-1]:g}"


def gain_stats(rows: list[dict]) -> dict:
    """Count, mean and median of PSNR/SSIM and of their gains over the blurred input."""
    if not rows:
        return {"count": 0}
    psnr_gain = np.array([r["psnr_db"] - r["blur_psnr_db"] for r in rows])
    ssim_gain = np.array([r["ssim"] - r["blur_ssim"] for r in rows])
    lengths = np.array([r["blur_length_px"] for r in rows])
    out: dict[str, float] = {"count": len(rows)}
    for k in METRICS:
        v = np.array([r[k] for r in rows])
        out[f"mean_{k}"], out[f"median_{k}"] = float(v.mean()), float(np.median(v))
    out.update(
        mean_psnr_gain_db=float(psnr_gain.mean()),
        median_psnr_gain_db=float(np.median(psnr_gain)),
        mean_ssim_gain=float(ssim_gain.mean()),
        median_ssim_gain=float(np.median(ssim_gain)),
        worse_count=int((psnr_gain < 0).sum()),
        median_blur_length_px=float(np.median(lengths)),
    )
    return out


def binned(rows: list[dict], edges: tuple[float, ...] = BLUR_BINS_PX) -> dict[str, dict]:
    """:func:`gain_stats` per blur-length bin, near-still triplets in their own bin."""
    groups: dict[str, list[dict]] = {}
    for r in sorted(rows, key=lambda r: r["blur_length_px"]):
        groups.setdefault(blur_bin(r["blur_length_px"], edges), []).append(r)
    return {name: gain_stats(g) for name, g in groups.items()}


@dataclass(frozen=True)
class EvalResult:
    """Per-image and mean metrics; ``blur_*`` score the blurred input itself; ``bins`` hold
    the gains per blur-length bin and ``blurred`` those over all but the near-still ones."""

    rows: list[dict] = field(default_factory=list)
    psnr_db: float = math.nan
    ssim: float = math.nan
    blur_psnr_db: float = math.nan
    blur_ssim: float = math.nan
    overall: dict = field(default_factory=dict)
    blurred: dict = field(default_factory=dict)
    bins: dict = field(default_factory=dict)
    conventions: str = CONVENTIONS

    def summary(self) -> dict:
        d = asdict(self)
        d.pop("rows")
        d["count"] = len(self.rows)
        return d


def median_length_px(heat_px: torch.Tensor | None) -> float:
    """Median over pixels of |q(1) − q(0)| (px), the manifest's ``blur_length_px.median``."""
    if heat_px is None:
        return math.nan
    return float(torch.hypot(heat_px[2] - heat_px[0], heat_px[3] - heat_px[1]).median())


def evaluate(
    model: DeblurNet,
    dataset: DeblurDataset,
    out_dir: str | Path | None = None,
    limit: int | None = None,
    progress: bool = False,
    options: RestoreOptions | None = None,
    work: bool = True,
    length_dataset: DeblurDataset | None = None,
) -> EvalResult:
    """Score ``model`` on every image of ``dataset`` (full size); write ``per_image.csv`` and
    ``summary.json`` to ``out_dir`` if given.

    Blur lengths for the bins come from the dataset's own heat maps (``length_dataset``'s when
    given: the true ones when ``dataset`` carries perturbed heat maps).
    """
    if limit is not None and limit < 1:
        raise GamdError(f"limit must be a positive number of images, got {limit}")
    model.eval()
    rows = []
    count = len(dataset) if limit is None else min(limit, len(dataset))
    bar_on = progress and sys.stderr.isatty()  # bars on a terminal only, never in logs
    for i in tqdm(range(count), disable=not bar_on, desc="eval", unit="img"):
        item = dataset.full(i)
        has_heat = dataset.triplets[i].heat is not None
        pred = restore(model, item["blur"], item["heat"], options, work=work)
        sharp = item["sharp"].permute(1, 2, 0).numpy()
        pred_hwc, blur_hwc = pred.permute(1, 2, 0).numpy(), item["blur"].permute(1, 2, 0).numpy()
        p, s = psnr_ssim(pred_hwc, sharp)
        bp, bs = psnr_ssim(blur_hwc, sharp)
        src = length_dataset.full(i) if length_dataset is not None else item
        scale = dataset.heat_scale_px if length_dataset is None else length_dataset.heat_scale_px
        length = median_length_px(src["heat"] * scale) if has_heat else math.nan
        rows.append(
            {
                "name": dataset.triplets[i].name,
                "psnr_db": p,
                "ssim": s,
                "blur_psnr_db": bp,
                "blur_ssim": bs,
                "blur_length_px": length,
                "bin": blur_bin(length),
                "vs_input_psnr_db": psnr_vs(pred_hwc, blur_hwc),
            }
        )

    def mean(k: str) -> float:
        return float(np.mean([r[k] for r in rows])) if rows else math.nan

    result = EvalResult(
        rows=rows,
        psnr_db=mean("psnr_db"),
        ssim=mean("ssim"),
        blur_psnr_db=mean("blur_psnr_db"),
        blur_ssim=mean("blur_ssim"),
        overall=gain_stats(rows),
        blurred=gain_stats([r for r in rows if r["bin"] != "near-still"]),
        bins=binned(rows),
    )
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        table = io.StringIO(newline="")
        w = csv.DictWriter(table, fieldnames=list(rows[0]) if rows else ["name"])
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out / "per_image.csv", table.getvalue())
        write_json_atomic(out / "summary.json", result.summary())
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


def gain_table(result: EvalResult) -> str:
    """A Markdown table of the gains over the input per blur-length bin (and overall)."""
    lines = [
        "| blur bin (px, median length) | images | input PSNR median | PSNR gain median | "
        "PSNR gain mean | SSIM gain median | SSIM gain mean | worse than input |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    rows = [*result.bins.items(), ("all but near-still", result.blurred), ("all", result.overall)]
    for name, g in rows:
        if not g.get("count"):
            continue
        lines.append(
            f"| {name} | {g['count']} | {g['median_blur_psnr_db']:.2f} | "
            f"{g['median_psnr_gain_db']:+.2f} | {g['mean_psnr_gain_db']:+.2f} | "
            f"{g['median_ssim_gain']:+.4f} | {g['mean_ssim_gain']:+.4f} | {g['worse_count']} |"
        )
    return "\n".join(lines)
