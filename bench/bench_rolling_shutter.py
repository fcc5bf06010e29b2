"""Why the shipped weights lost on the demo's data, and what recentring does (issue 19).

The demo (``make demo``) synthesises 256 × 192 triplets with its fitted 720p phone-class
calibration (rolling shutter, ~24 ms readout), real shake and mild noise. This benchmark builds
the same kind of set four times — rolling or global shutter (``--readout-ms 0``), with or
without noise; same seed, so the same photos, crops and shake segments — and scores the shipped
GAMD and GAMD-only on each, with and without the rolling-shutter recentring of
:mod:`gamd.restorer`, plus the recentred input alone (no network).

    PYTHONPATH=$PWD .venv/bin/python bench/bench_rolling_shutter.py [--calib demo_out/calib.yaml]
        [--count 48] [--out bench_out/rolling_shutter]

Without ``--calib``: the demo's default phone camera (1280 × 720, f = 1000 px, 20 ms readout).
Prints JSON (median / mean PSNR gain over the blurred input, images made worse) and writes it to
``OUT/results.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
VARIANTS = {  # name: extra synth arguments
    "rolling_noise": ["--noise", "2e-4,2e-3"],
    "rolling_clean": [],
    "global_noise": ["--noise", "2e-4,2e-3", "--readout-ms", "0"],
    "global_clean": ["--readout-ms", "0"],
}


def _stats(gains: list[float]) -> dict:
    return {
        "median_db": statistics.median(gains),
        "mean_db": statistics.mean(gains),
        "worse": sum(g < 0 for g in gains),
        "count": len(gains),
    }


def score(root: Path) -> dict:
    """Gains of the shipped nets (recentring on / off) and of the recentred input alone."""
    import torch

    from gamd.checkpoint import load_model
    from gamd.data import DeblurDataset
    from gamd.evaluate import median_length_px, psnr_ssim, restore
    from gamd.restorer import recentre
    from gamd.weights import shipped_weights

    nets = {n: load_model(shipped_weights(n)) for n in ("gamd", "gamd_only")}
    gains: dict[str, list[float]] = {}
    lengths = []
    for split in ("train", "test"):
        if not (root / split).is_dir():
            continue
        scale = nets["gamd"][1].data.heat_scale_px
        ds = DeblurDataset(root, split, crop=None, augment=False, heat_scale_px=scale)
        for i in range(len(ds)):
            item = ds.full(i)
            sharp = item["sharp"].permute(1, 2, 0).numpy()
            base = psnr_ssim(item["blur"].permute(1, 2, 0).numpy(), sharp)[0]
            heat_px = item["heat"] * scale
            lengths.append(median_length_px(heat_px))
            with torch.inference_mode():
                (b,), _ = recentre([item["blur"][None]], heat_px[None])
            p = psnr_ssim(b[0].permute(1, 2, 0).numpy(), sharp)[0]
            gains.setdefault("recentred input alone", []).append(p - base)
            for name, (model, cfg, _) in nets.items():
                for on in (True, False):
                    opts = replace(cfg.data.restore_options(), recentre=on)
                    out = restore(model, item["blur"], item["heat"], opts)
                    p = psnr_ssim(out.permute(1, 2, 0).numpy(), sharp)[0]
                    key = f"{name}{'' if on else ' without recentring'}"
                    gains.setdefault(key, []).append(p - base)
    return {
        "median_blur_px": statistics.median(lengths),
        **{k: _stats(v) for k, v in gains.items()},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--calib", type=Path, default=None, help="calibration (default: demo's)")
    ap.add_argument("--count", type=int, default=48)
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--shared", type=Path, default=SHARED)
    ap.add_argument("--out", type=Path, default=REPO / "bench_out" / "rolling_shutter")
    args = ap.parse_args(argv)
    from blurtrack.cli import main as bt
    from blurtrack.cli.demo import demo_calibration
    from blurtrack.io.calibration import write_calibration

    args.out.mkdir(parents=True, exist_ok=True)
    calib = args.calib
    if calib is None:
        calib = args.out / "demo_calibration.yaml"
        write_calibration(demo_calibration(), calib)
    results: dict = {"calib": str(calib), "count": args.count, "size": args.size}
    for name, extra in VARIANTS.items():
        root = args.out / name
        cmd = ["synth", "--calib", str(calib), "--images"]
        cmd += [str(args.shared / "backgrounds" / "bsds500"), "--out", str(root)]
        cmd += ["--gyro", str(args.shared / "real" / "gyrodeblurnet-shake")]
        cmd += ["--count", str(args.count), "--size", args.size, "--seed", "0", "--quiet"]
        if bt([*cmd, *extra]) != 0:
            return 2
        results[name] = score(root)
    text = json.dumps(results, indent=2)
    (args.out / "results.json").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
