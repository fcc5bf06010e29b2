"""The shipped-weights part of ``bench/bench_gamd.py --shipped`` (issue 19's targets).

Test sets, all from BSDS500 test (never trained on) with the real GyroDeblurNet shake:

* ``test256`` / ``test512``: 256² at focal 1500 px and 512² at focal 3000 px (10–30 ms
  exposures: median blur ~15 and ~30 px); the targets are the median PSNR gains over the
  blurred input in the bins up to 30 px (256²) and 60 px (512²).
* ``still256`` / ``still512``: the same cameras with exposures of 0.05–0.4 ms (0.025–0.2 ms at
  512²), so that most triplets have a median blur under 0.5 px, ``gamd eval``'s near-still bin.
  Do no harm: each near-still output must equal its input to within 45 dB PSNR (output against
  the blurred input, not the sharp image). Triplets of these sets that land above 0.5 px are
  counted and reported with the rest of their set, outside the near-still figure.

GAMD is restored as shipped (recentring, gate, working resolution, the weights' own
self-ensemble unless ``--ensemble``), also at full size (no working resolution and, to keep
this diagnostic cheap, no ensemble), and compared with its no-heat-map twin on the very same
images.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

#: The shipped-weights test sets: (split, size, focal px, seed, max blur of the target bin).
SHIPPED_TESTS = (("test256", (256, 256), 1500.0, 2, 30.0), ("test512", (512, 512), 3000.0, 3, 60.0))
#: Near-still sets: (split, size, focal px, seed, exposure range in ms for synth).
STILL_TESTS = (
    ("still256", (256, 256), 1500.0, 5, "0.05:0.4"),
    ("still512", (512, 512), 3000.0, 6, "0.025:0.2"),
)
#: Targets (issue 19): median PSNR gain over the input in the target bin, per size.
SHIPPED_TARGET_DB = {"test256": 2.0, "test512": 1.0}
#: Do no harm: near-still outputs within this PSNR (dB) of their input.
NEAR_STILL_TARGET_DB = 45.0
#: Images timed per size for the self-ensemble's cost.
TIMED_IMAGES = 8


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The ``--shipped*`` options of bench_gamd.py."""
    p.add_argument(
        "--shipped",
        action="store_true",
        help="evaluate the shipped weights (gamd/weights) on BSDS500 test at 256² and 512² "
        "against the issue's targets instead of training the four networks",
    )
    p.add_argument("--shipped-count-256", type=int, default=100)
    p.add_argument("--shipped-count-512", type=int, default=60)
    p.add_argument(
        "--shipped-count-still", type=int, default=40, help="triplets per near-still set"
    )
    p.add_argument(
        "--shipped-gamd", type=Path, default=None, help="with --shipped: these GAMD weights instead"
    )
    p.add_argument(
        "--shipped-twin", type=Path, default=None, help="with --shipped: these GAMD-only weights"
    )
    p.add_argument(
        "--ensemble",
        type=int,
        choices=(1, 2, 4, 8),
        default=None,
        help="with --shipped: self-ensemble size for both networks (default: the weights' own)",
    )


def near_still_stats(rows: list[dict]) -> dict:
    """Do-no-harm figures of the near-still rows: PSNR of output against input (min, median;
    ``inf`` = identical) and against the sharp image, and the pass/fail of the 45 dB target."""
    still = [r for r in rows if r["bin"] == "near-still"]
    out: dict = {"count": len(still), "outside_near_still": len(rows) - len(still)}
    if not still:
        return out
    vs_in = [r["vs_input_psnr_db"] for r in still]
    out.update(
        min_vs_input_psnr_db=min(vs_in),
        median_vs_input_psnr_db=statistics.median(vs_in),
        identical_to_input=sum(v == float("inf") for v in vs_in),
        median_input_psnr_db=statistics.median(r["blur_psnr_db"] for r in still),
        median_output_psnr_db=statistics.median(r["psnr_db"] for r in still),
        min_psnr_gain_db=min(r["psnr_db"] - r["blur_psnr_db"] for r in still),
        max_blur_length_px=max(r["blur_length_px"] for r in still),
        met=min(vs_in) >= NEAR_STILL_TARGET_DB,
    )
    return out


def _ensemble_cost(model, ds, opts, ensemble: int) -> dict:
    """Median seconds per image restoring the first images with and without the ensemble."""
    from gamd.evaluate import restore

    def timed(o) -> float:
        times = []
        for i in range(min(TIMED_IMAGES, len(ds))):
            item = ds.full(i)
            t0 = time.perf_counter()
            restore(model, item["blur"], item["heat"], o)
            times.append(time.perf_counter() - t0)
        return statistics.median(times) if times else float("nan")

    plain, ens = timed(replace(opts, ensemble=1)), timed(replace(opts, ensemble=ensemble))
    return {
        "ensemble": ensemble,
        "s_per_image_plain": plain,
        "s_per_image": ens,
        "ratio": ens / plain,
    }


def shipped(args: argparse.Namespace) -> dict:
    """Shipped GAMD and its twin on BSDS500 test with real shake: binned gains over the input,
    the working resolution against full-size restoration, near-still sets, and the targets."""
    from gamd.checkpoint import load_model
    from gamd.data import DeblurDataset
    from gamd.evaluate import evaluate, gain_stats, gain_table
    from gamd.weights import shipped_weights

    sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/train_shipped.py
    from train_shipped import link_split, synth

    bg = args.shared / "backgrounds" / "bsds500" / "test"
    data = args.out / "data"
    counts = {"test256": args.shipped_count_256, "test512": args.shipped_count_512}
    counts.update({split: args.shipped_count_still for split, *_ in STILL_TESTS})
    out: dict = {"tests": {}, "near_still": {}}
    files = {n: shipped_weights(n) for n in ("gamd", "gamd_only")}
    files["gamd"] = args.shipped_gamd or files["gamd"]
    files["gamd_only"] = args.shipped_twin or files["gamd_only"]
    nets = {n: load_model(f) for n, f in files.items()}
    opts = {}
    for n, (_, cfg, _) in nets.items():
        o = cfg.data.restore_options()
        opts[n] = o if args.ensemble is None else replace(o, ensemble=args.ensemble)
    out["weights"] = {
        n: {"step": v[2], "file": str(files[n]), "ensemble": opts[n].ensemble}
        for n, v in nets.items()
    }
    tables = []

    def dataset(split: str, name: str) -> DeblurDataset:
        scale = opts[name].heat_scale_px
        return DeblurDataset(data, split, crop=None, augment=False, heat_scale_px=scale)

    def run(split: str, name: str, work: bool):
        model, ds = nets[name][0], dataset(split, name)
        o = opts[name] if work else replace(opts[name], ensemble=1)  # a diagnostic: keep it cheap
        t1 = time.perf_counter()
        res = evaluate(model, ds, options=o, work=work, limit=args.eval_limit)
        return res, time.perf_counter() - t1

    for split, size, focal, seed, max_blur in SHIPPED_TESTS:
        t0 = time.perf_counter()
        synth(bg, args.out / "synth" / split, size, focal, seed, counts[split], args.shared)
        link_split(args.out / "synth" / split, data / split, split)
        entry: dict = {"size": list(size), "focal_px": focal, "synth_s": time.perf_counter() - t0}
        for name, work in (("gamd", True), ("gamd", False), ("gamd_only", True)):
            res, secs = run(split, name, work)
            key = name if work else f"{name} (full size, no working resolution, no ensemble)"
            target_rows = [
                r for r in res.rows if r["bin"] != "near-still" and r["blur_length_px"] <= max_blur
            ]
            entry[key] = {
                "eval_s": secs,
                "bins": res.bins,
                "blurred": res.blurred,
                "overall": res.overall,
                f"target_bin_le_{max_blur:g}px": gain_stats(target_rows),
                "near_still": near_still_stats(res.rows),
            }
            tables.append(f"### {split} {key}\n\n{gain_table(res)}\n")
        tgt = entry["gamd"][f"target_bin_le_{max_blur:g}px"]
        twin = entry["gamd_only"][f"target_bin_le_{max_blur:g}px"]
        entry["targets"] = {
            "median_gain_db": tgt.get("median_psnr_gain_db"),
            "target_db": SHIPPED_TARGET_DB[split],
            "met": bool(tgt.get("count"))
            and tgt["median_psnr_gain_db"] >= SHIPPED_TARGET_DB[split],
            "gamd_ahead_of_twin": bool(tgt.get("count"))
            and tgt["median_psnr_gain_db"] > twin["median_psnr_gain_db"],
        }
        if opts["gamd"].ensemble > 1:
            model, ds = nets["gamd"][0], dataset(split, "gamd")
            entry["ensemble_cost"] = _ensemble_cost(model, ds, opts["gamd"], opts["gamd"].ensemble)
        out["tests"][split] = entry
    for split, size, focal, seed, exposure in STILL_TESTS:
        t0 = time.perf_counter()
        extra = ["--exposure-ms", exposure]
        synth(bg, args.out / "synth" / split, size, focal, seed, counts[split], args.shared, extra)
        link_split(args.out / "synth" / split, data / split, split)
        entry = {"size": list(size), "focal_px": focal, "exposure_ms": exposure}
        entry["synth_s"] = time.perf_counter() - t0
        for name in ("gamd", "gamd_only"):
            res, secs = run(split, name, True)
            entry[name] = {
                "eval_s": secs,
                "bins": res.bins,
                "near_still": near_still_stats(res.rows),
            }
            tables.append(f"### {split} {name}\n\n{gain_table(res)}\n")
        entry["targets"] = {
            "near_still_target_db": NEAR_STILL_TARGET_DB,
            "met": all(entry[n]["near_still"].get("met", False) for n in ("gamd", "gamd_only")),
        }
        out["near_still"][split] = entry
    out["tables"] = "\n".join(tables)
    return out
