"""GAMD benchmark: the paper's comparison at CPU scale, plus calibration-error robustness.

1. Synthesise one dataset with ``blurtrack synth`` from ../shared/data/backgrounds/bsds500
   (train + val images -> training split, test images -> test split) driven by real shake
   (../shared/data/real/gyrodeblurnet-shake).
2. Train GAMD, GAMD-only (no heat maps), MIMO-UNet and MIMO-Pro with the same budget (same
   crops, steps, batch, seed, learning-rate schedule), CPU by default.
3. Evaluate PSNR/SSIM on the test split; parameters, MACs and CPU latency at 256² and
   1280 × 720; ratios against MIMO-UNet measured in the same run.
4. Re-evaluate the heat-map networks with heat maps from a perturbed calibration (time
   offset off by 2 ms and 5 ms, 1 sigma per image; gyro noise) on the very same blurred
   images (synth draws the errors per triplet; the blur always uses the true model).

Prints one JSON object; also writes OUT/results.json and OUT/results.md. Budget options
(--steps, --count-*) scale it from a smoke run to the hour-long run on 2 cores.
``--shipped`` instead evaluates the shipped weights against issue 19's targets, near-still
sets included (bench/gamd_shipped.py).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from gamd_shipped import add_arguments, shipped  # noqa: E402

NETS = ("gamd", "gamd_only", "mimo_unet", "mimo_pro")
#: Smallest clean heat-map gain (dB) whose surviving share is reported.
MIN_GAIN_DB = 0.05


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=REPO / "bench_out" / "gamd")
    p.add_argument("--shared", type=Path, default=REPO.parent / "shared" / "data")
    p.add_argument(
        "--dataset",
        type=Path,
        default=None,
        help="use this dataset (train/test splits) instead of synthesising one",
    )
    p.add_argument("--nets", default=",".join(NETS))
    p.add_argument("--preset", default="tiny")
    p.add_argument("--steps", type=int, default=6000, help="training steps per network")
    p.add_argument("--milestones", default="", help="comma list; default: 2/3 of steps")
    p.add_argument("--crop", type=int, default=64)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--heat-scale-px", type=float, default=16.0)
    p.add_argument("--size", default="256x256", help="synthesised image size WxH")
    p.add_argument("--count-train", type=int, default=400, help="triplets from bsds500/train")
    p.add_argument("--count-val", type=int, default=200, help="triplets from bsds500/val")
    p.add_argument("--count-test", type=int, default=200, help="triplets from bsds500/test")
    p.add_argument(
        "--focal-px",
        type=float,
        default=600.0,
        help="focal length of the synthetic camera at --size (sets the blur length)",
    )
    p.add_argument("--workers", type=int, default=1, help="synth --workers")
    p.add_argument("--synth-cmd", default=f"{shlex.quote(sys.executable)} -m blurtrack synth")
    p.add_argument("--synth-extra", default="", help="extra arguments for every synth call")
    p.add_argument(
        "--perturb-flag",
        default="--robust",
        help="synth option whose value perturbs the calibration behind the heat maps "
        "only (blur from the true calibration)",
    )
    p.add_argument(
        "--perturbations",
        default="timeshift_ms=2;timeshift_ms=5;gyro_noise=0.02",
        help="';'-separated values of --perturb-flag, one evaluation each",
    )
    p.add_argument("--eval-limit", type=int, default=None)
    p.add_argument("--time-repeats", type=int, default=3)
    p.add_argument("--time-paper", action="store_true", help="also time the paper-size nets")
    add_arguments(p)
    return p.parse_args(argv)


def write_calibration(path: Path, size: tuple[int, int], focal_px: float) -> None:
    """A global-shutter pinhole camera at the synthesised size."""
    from blurtrack.geometry.calibration import Calibration
    from blurtrack.geometry.camera import Camera
    from blurtrack.io.calibration import write_calibration

    w, h = size
    cam = Camera(resolution=(w, h), intrinsics=(focal_px, focal_px, (w - 1) / 2, (h - 1) / 2))
    write_calibration(Calibration(camera=cam), path)


def run_synth(
    args: argparse.Namespace,
    calib: Path,
    images: Path,
    out: Path,
    count: int | None,
    extra: list[str],
) -> None:
    gyro = args.shared / "real" / "gyrodeblurnet-shake" / "gyro_train.txt"
    cmd = [
        *shlex.split(args.synth_cmd),
        "--calib",
        str(calib),
        "--gyro",
        str(gyro),
        "--images",
        str(images),
        "--out",
        str(out),
        "--size",
        args.size,
        "--seed",
        str(args.seed),
        "--workers",
        str(args.workers),
    ]
    if count is not None:
        cmd += ["--count", str(count)]
    cmd += shlex.split(args.synth_extra) + extra
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"bench_gamd: synth failed ({' '.join(cmd)}): {proc.stderr[-800:]}")


def link_groups(src: Path, dst_split: Path, tag: str, what: str = "") -> int:
    """Symlink every ``src/<any split>/<name>`` (or its ``what`` subfolder) into
    ``dst_split/<tag>_<split>_<name>``; returns the number of groups."""
    n = 0
    for group in sorted(src.glob("*/*/blur")):
        g = group.parent
        dst = dst_split / f"{tag}_{g.parent.name}_{g.name}"
        dst.mkdir(parents=True, exist_ok=True)
        for sub in ("blur", "sharp", "heat") if not what else (what,):
            link = dst / sub
            if (g / sub).is_dir() and not link.exists():
                link.symlink_to((g / sub).resolve(), target_is_directory=True)
        n += 1
    return n


def blur_lengths(dataset: Path) -> dict:
    """Median over triplets of the per-image median blur length (px) in synth's manifest."""
    import json as _json
    import statistics

    def find(obj):
        if isinstance(obj, dict):
            if isinstance(obj.get("blur_length_px"), dict):
                return obj["blur_length_px"]
            for v in obj.values():
                found = find(v)
                if found is not None:
                    return found
        return None

    medians, maxima = [], []
    path = dataset / "manifest.jsonl"
    for line in path.read_text().splitlines() if path.is_file() else []:
        bl = find(_json.loads(line))
        if bl is not None:
            medians.append(bl["median"])
            maxima.append(bl["max"])
    if not medians:
        return {}
    return {
        "median_of_medians_px": statistics.median(medians),
        "median_of_maxima_px": statistics.median(maxima),
        "triplets": len(medians),
    }


def same_blur(a: Path, b: Path) -> bool:
    """Whether two synth outputs hold byte-identical blurred images."""
    fa = sorted(p.relative_to(a) for p in a.glob("*/*/blur/*.png"))
    fb = sorted(p.relative_to(b) for p in b.glob("*/*/blur/*.png"))
    return fa == fb and all((a / f).read_bytes() == (b / f).read_bytes() for f in fa)


def build_dataset(args: argparse.Namespace) -> tuple[Path, dict[str, Path | str]]:
    """The train/test dataset and the heat roots of the perturbed calibrations."""
    bg = args.shared / "backgrounds" / "bsds500"
    synth_dir, data = args.out / "synth", args.out / "data"
    size = tuple(int(v) for v in args.size.lower().split("x"))
    calib = args.out / "calib_true.yaml"
    args.out.mkdir(parents=True, exist_ok=True)
    write_calibration(calib, size, args.focal_px)
    for folder, count in (
        ("train", args.count_train),
        ("val", args.count_val),
        ("test", args.count_test),
    ):
        run_synth(args, calib, bg / folder, synth_dir / folder, count, [])
    link_groups(synth_dir / "train", data / "train", "train")
    link_groups(synth_dir / "val", data / "train", "val")
    link_groups(synth_dir / "test", data / "test", "test")
    perturbed: dict[str, Path | str] = {}
    for spec in filter(None, (v.strip() for v in args.perturbations.split(";"))):
        name = spec.replace("=", "_").replace(",", "+")
        out = synth_dir / f"test_{name}"
        try:
            run_synth(args, calib, bg / "test", out, args.count_test, [args.perturb_flag, spec])
        except SystemExit as exc:
            perturbed[spec] = f"unavailable: {exc}"
            continue
        if not same_blur(synth_dir / "test", out):
            perturbed[spec] = "unavailable: the perturbation changed the blurred images"
            continue
        link_groups(out, args.out / f"heat_{name}" / "test", "test", what="heat")
        perturbed[spec] = args.out / f"heat_{name}"
    return data, perturbed


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import torch

    from gamd.checkpoint import load_model
    from gamd.config import RunConfig
    from gamd.data import DeblurDataset
    from gamd.evaluate import evaluate, summary_table
    from gamd.nets import build_model
    from gamd.profile import profile
    from gamd.train import train

    torch.set_num_threads(args.threads)
    if args.dataset is None and not (args.shared / "backgrounds" / "bsds500").is_dir():
        print(json.dumps({"skipped": f"{args.shared}/backgrounds/bsds500 not found"}))
        return 0
    if args.shipped:
        res = shipped(args)
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "shipped.json").write_text(json.dumps(res, indent=2, default=str))
        (args.out / "shipped.md").write_text(res["tables"])
        print(json.dumps(res, indent=2, default=str))
        return 0
    t0 = time.perf_counter()
    if args.dataset is not None:
        data, perturbed = args.dataset, {}
    else:
        data, perturbed = build_dataset(args)
    synth_s = time.perf_counter() - t0
    nets = [n for n in args.nets.split(",") if n]
    milestones = (
        [int(m) for m in args.milestones.split(",") if m]
        if args.milestones
        else [max(1, 2 * args.steps // 3)]
    )
    results: dict = {
        "config": {k: str(v) for k, v in vars(args).items()},
        "synth_seconds": synth_s,
        "nets": {},
        "test_blur_length": blur_lengths(args.out / "synth" / "test"),
    }
    evals, evals_perturbed = {}, {}
    for name in nets:
        cfg = RunConfig.from_dict(
            {
                "model": {"name": name, "preset": args.preset},
                "data": {"root": str(data), "crop": args.crop, "heat_scale_px": args.heat_scale_px},
                "train": {
                    "out_dir": str(args.out / "runs" / name),
                    "steps": args.steps,
                    "batch_size": args.batch,
                    "lr": args.lr,
                    "milestones": milestones,
                    "seed": args.seed,
                    "threads": args.threads,
                    "checkpoint_every": max(1, args.steps // 4),
                    "progress": False,
                },
            }
        )
        res = train(cfg, resume="auto")
        model, _, _ = load_model(args.out / "runs" / name / "checkpoints" / "last.pt")
        test = DeblurDataset(
            data,
            "test",
            crop=None,
            augment=False,
            heat_scale_px=args.heat_scale_px,
            require_heat=model.uses_heat,
        )
        ev = evaluate(model, test, out_dir=args.out / "eval" / name, limit=args.eval_limit)
        evals[name] = ev
        entry = {
            "train_seconds": res.seconds,
            "final_loss_mean100": sum(res.losses[-100:]) / max(1, len(res.losses[-100:])),
            **ev.summary(),
        }
        entry["tiny" if args.preset == "tiny" else args.preset] = profile(
            model, [(256, 256), (720, 1280)], repeats=args.time_repeats
        )
        entry["paper"] = profile(
            build_model(name, "paper"),
            [(256, 256), (720, 1280)],
            repeats=1,
            time_it=args.time_paper,
        )
        if model.uses_heat:
            entry["perturbed"] = {}
            for pname, root in perturbed.items():
                if isinstance(root, str):
                    entry["perturbed"][pname] = root
                    continue
                pt = DeblurDataset(
                    data,
                    "test",
                    crop=None,
                    augment=False,
                    heat_root=root,
                    heat_scale_px=args.heat_scale_px,
                )
                pev = evaluate(
                    model, pt, out_dir=args.out / "eval" / f"{name}_{pname}", limit=args.eval_limit
                )
                evals_perturbed[f"{name} ({pname})"] = pev
                entry["perturbed"][pname] = pev.summary()
        results["nets"][name] = entry
    results["ratios_vs_mimo_unet"] = ratios(results["nets"], args.preset)
    results["heat_gain_surviving"] = surviving_gain(results["nets"])
    results["table"] = summary_table({**evals, **evals_perturbed})
    (args.out / "results.json").write_text(json.dumps(results, indent=2, default=str))
    (args.out / "results.md").write_text(results["table"] + "\n")
    print(json.dumps(results, indent=2, default=str))
    return 0


def ratios(nets: dict, preset: str) -> dict:
    """PSNR difference (dB) and latency/MAC ratios of each net against MIMO-UNet."""
    base = nets.get("mimo_unet")
    if base is None:
        return {}
    key = "tiny" if preset == "tiny" else preset
    out = {}
    for name, e in nets.items():
        r = {"psnr_gain_db": e["psnr_db"] - base["psnr_db"], "ssim_gain": e["ssim"] - base["ssim"]}
        for size, ms in e[key]["cpu_ms_median"].items():
            r[f"cpu_ms_ratio_{size}"] = ms / base[key]["cpu_ms_median"][size]
        r["macs_ratio_256x256"] = e[key]["macs"]["256x256"] / base[key]["macs"]["256x256"]
        out[name] = r
    return out


def surviving_gain(nets: dict) -> dict:
    """Share of the heat-map gain (heat net minus its no-heat twin, dB) kept under each
    perturbed calibration."""
    out = {}
    for heat_net, plain in (("gamd", "gamd_only"), ("mimo_pro", "mimo_unet")):
        if heat_net not in nets or plain not in nets:
            continue
        gain = nets[heat_net]["psnr_db"] - nets[plain]["psnr_db"]
        out[heat_net] = {"clean_gain_db": gain}
        for pname, s in nets[heat_net].get("perturbed", {}).items():
            if isinstance(s, dict):
                g = s["psnr_db"] - nets[plain]["psnr_db"]
                # a share of a gain within the noise means nothing: only above 0.05 dB
                out[heat_net][pname] = {
                    "gain_db": g,
                    "fraction": g / gain if gain > MIN_GAIN_DB else None,
                }
    return out


if __name__ == "__main__":
    sys.exit(main())
