"""``blurtrack synth`` (training triplets) and ``blurtrack synth-merge`` (combine shards)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, cast

from blurtrack.cli.progress import Progress, add_quiet_arg


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "synth",
        help="synthesise calibrated training triplets (sharp, blur, heat maps)",
        description="Blur sharp photographs along the calibrated gyro-driven trajectories and "
        "write a GoPro-style dataset with heat maps and a manifest "
        "(docs/synthesis.md). Resumable, deterministic by seed, shardable.",
    )
    p.add_argument("--calib", required=True, help="calibration file (Kalibr layout)")
    p.add_argument(
        "--gyro",
        required=True,
        help="gyro source: a session folder, a shake file (or its folder), or "
        "synthetic[:RMS_RADPS]",
    )
    p.add_argument("--images", required=True, help="folder of sharp photographs")
    p.add_argument("--out", required=True, help="dataset folder")
    p.add_argument("--count", type=int, default=100, help="number of triplets (default 100)")
    p.add_argument("--size", default="1280x720", help="output WxH (default 1280x720)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shard", default="0/1", help="build only indices i %% N == I (I/N)")
    p.add_argument("--workers", type=int, default=1, help="worker processes")
    p.add_argument(
        "--cluster",
        default=None,
        metavar="local:N|tcp://HOST:PORT",
        help="build on a dask.distributed cluster: N local worker processes, or a running "
        "scheduler (one task per triplet; docs/synthesis.md)",
    )
    p.add_argument(
        "--shared-fs",
        action="store_true",
        help="with --cluster: workers write the files into --out themselves (it must be "
        "mounted at the same path on every worker); default: they return them to this client",
    )
    p.add_argument(
        "--cluster-timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds to wait for the scheduler and its first worker (default 10)",
    )
    p.add_argument("--mode", choices=("exact", "paper"), default="exact")
    p.add_argument("--exposure-ms", default="10:30", help="exposure, LO:HI range or a value")
    p.add_argument(
        "--readout-ms",
        type=float,
        default=None,
        help="rolling-shutter readout (default: the calibration's)",
    )
    p.add_argument("--noise", default="0,0", help="Poisson scale and read-noise sigma (linear)")
    p.add_argument(
        "--saturation",
        default="1,0.9",
        help="largest highlight gain and its linear threshold (gain 1: off)",
    )
    p.add_argument("--jpeg", type=int, default=0, help="JPEG quality of the blur (0: off)")
    p.add_argument(
        "--srgb-average",
        action="store_true",
        help="average in sRGB values instead of linear light (ablation)",
    )
    p.add_argument(
        "--robust",
        default="",
        help="heat maps from a perturbed model: timeshift_ms=,gyro_noise=,"
        "gyro_bias=,focal_rel=,principal_px=,readout_rel= (1-sigma)",
    )
    p.add_argument(
        "--heat-stride",
        type=int,
        default=16,
        help="heat-map evaluation stride (px; 16 adds < 0.01 px)",
    )
    p.add_argument(
        "--min-blur-px",
        type=float,
        default=0.0,
        metavar="PX",
        help="draw a triplet again (deterministically, by index) while its median blur length "
        "is under PX; the build reports how many draws fell under it (default 0: off)",
    )
    p.add_argument("--heat-samples", type=int, default=16, help="trajectory samples per pixel")
    p.add_argument("--max-step-px", type=float, default=0.5)
    p.add_argument("--grid-px", type=int, default=16)
    p.add_argument("--border", choices=("reflect", "constant"), default="reflect")
    p.add_argument("--no-upscale", action="store_true", help="refuse photos smaller than --size")
    p.add_argument(
        "--extras",
        action="store_true",
        help="also write mask/<stem>.png (validity) and fit/<stem>.npy (fit error)",
    )
    p.add_argument(
        "--png-compression",
        type=int,
        default=0,
        metavar="LEVEL",
        help="PNG deflate level 0-9 of sharp/blur (0: fastest, default)",
    )
    p.add_argument("--group", type=int, default=100, help="triplets per <name> folder")
    add_quiet_arg(p)
    p.set_defaults(func=run)

    m = subparsers.add_parser(
        "synth-merge",
        help="combine dataset shards into one manifest",
        description="Merge manifest-shard*.jsonl of DATASET and move the "
        "triplets of other shard folders into it.",
    )
    m.add_argument("dataset")
    m.add_argument("shards", nargs="*", help="shard folders built elsewhere")
    m.add_argument(
        "--allow-missing",
        action="store_true",
        help="merge even if triplets are missing (default: refuse, changing nothing)",
    )
    m.set_defaults(func=run_merge)


def _floats(text: str, n: int, what: str) -> list[float]:
    from blurtrack.errors import SynthesisError

    try:
        vals = [float(v) for v in text.replace(":", ",").split(",")]
    except ValueError:
        raise SynthesisError(f"{what}: {text!r} is not a list of numbers") from None
    if len(vals) == 1 and n == 2:
        vals = vals * 2
    if len(vals) != n:
        raise SynthesisError(f"{what} takes {n} numbers, got {text!r}")
    return vals


def spec_from_args(args: argparse.Namespace):
    from blurtrack.errors import SynthesisError
    from blurtrack.io.calibration import calibration_to_dict, read_calibration
    from blurtrack.synth.dataset import DatasetSpec
    from blurtrack.synth.perturb import Perturbation
    from blurtrack.synth.photometry import Photometry
    from blurtrack.synth.render import RenderSettings
    from blurtrack.synth.triplet import TripletParams

    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise SynthesisError(f"--size must be WxH, got {args.size!r}") from None
    shot, read = _floats(args.noise, 2, "--noise")
    gain, thresh = (
        _floats(args.saturation, 2, "--saturation")
        if "," in args.saturation
        else (float(args.saturation), 0.9)
    )
    params = TripletParams(
        size=(w, h),
        exposure_ms=cast(
            "tuple[float, float]", tuple(_floats(args.exposure_ms, 2, "--exposure-ms"))
        ),
        mode=args.mode,
        photometry=Photometry(
            linear=not args.srgb_average,
            saturation_threshold=thresh,
            saturation_gain=gain,
            noise_shot=shot,
            noise_read=read,
            jpeg_quality=args.jpeg,
        ),
        perturbation=Perturbation.parse(args.robust),
        render=RenderSettings(
            max_step_px=args.max_step_px, grid_px=args.grid_px, border=args.border
        ),
        heat_stride=args.heat_stride,
        heat_n_t=args.heat_samples,
        upscale=not args.no_upscale,
        readout_ms=args.readout_ms,
        min_blur_px=args.min_blur_px,
    )
    calib = read_calibration(args.calib)
    gyro = args.gyro if args.gyro.startswith("synthetic") else str(Path(args.gyro).resolve())
    return DatasetSpec(
        calib=calibration_to_dict(calib),
        gyro=gyro,
        images=str(Path(args.images).resolve()),
        count=args.count,
        seed=args.seed,
        params=params,
        group=args.group,
        extras=args.extras,
    )


def run(args: argparse.Namespace) -> int:
    from blurtrack.errors import SynthesisError
    from blurtrack.io.atomic import write_json_atomic
    from blurtrack.io.guard import check_output
    from blurtrack.synth.dataset import build, check_synth_size, parse_shard

    if args.workers < 1:
        raise SynthesisError("--workers must be >= 1")
    if args.cluster is not None and args.workers != 1:
        raise SynthesisError("--workers and --cluster exclude each other (local:N for N cores)")
    if args.shared_fs and args.cluster is None:
        raise SynthesisError("--shared-fs applies to --cluster builds only")
    check_output(
        args.out,
        folder=True,
        force=True,  # an earlier build of the same spec is resumed, another one refused
        inputs=[args.calib],
        input_folders=[args.images],
    )
    spec = spec_from_args(args)
    check_synth_size(spec.params, args.workers if args.cluster is None else 1)
    shard = parse_shard(args.shard)
    with Progress("synth", "triplet", args.quiet) as bar:
        if args.cluster is None:
            result = build(spec, args.out, shard, args.workers, bar, args.png_compression)
        else:
            from blurtrack.synth.cluster import build_on_cluster

            result = build_on_cluster(
                spec,
                args.out,
                args.cluster,
                shard,
                args.shared_fs,
                bar,
                args.png_compression,
                args.cluster_timeout,
            )
    summary = {
        "command": "synth",
        "shard": list(shard),
        "count": spec.count,
        "mode": spec.params.mode,
        "size": list(spec.params.size),
        "workers": args.workers if args.cluster is None else None,
        "cluster": args.cluster,
        "shared_fs": bool(args.shared_fs),
        **result.to_dict(),
    }
    name = "summary.json" if shard[1] == 1 else f"summary-shard{shard[0]}.json"
    write_json_atomic(Path(args.out) / name, summary)
    rate = summary["triplets_per_s"]
    print(
        f"synth: {result.made} made, {result.skipped} already done, of {result.planned} in "
        f"shard {shard[0]}/{shard[1]}"
        + (f" ({rate:.2f} triplets/s)" if rate else "")
        + f" -> {args.out}"
    )
    if result.remade_broken:
        shown = ", ".join(str(i) for i in result.remade_broken[:10])
        more = ", ..." if len(result.remade_broken) > 10 else ""
        print(
            f"synth: made {len(result.remade_broken)} finished triplet(s) again whose files were "
            f"zero-byte, truncated or undecodable: {shown}{more}"
        )
    if spec.params.min_blur_px:
        drawn = result.made + result.under_min_blur
        print(
            f"synth: {result.under_min_blur} of {drawn} draws had a median blur under "
            f"--min-blur-px {spec.params.min_blur_px:g} and were drawn again"
            + (
                f" ({result.under_min_blur_total} over all finished triplets)"
                if result.skipped
                else ""
            )
        )
    return 0


def run_merge(args: argparse.Namespace) -> int:
    from blurtrack.io.atomic import write_json_atomic
    from blurtrack.io.guard import check_output
    from blurtrack.synth.merge import merge

    check_output(args.dataset, folder=True, force=True, input_folders=args.shards)
    summary = {"command": "synth-merge", **merge(args.dataset, args.shards, args.allow_missing)}
    write_json_atomic(Path(args.dataset) / "summary.json", summary)
    print(
        f"synth-merge: {summary['triplets']} of {summary['count']} triplets in "
        f"{args.dataset}"
        + (f", {summary['missing']} missing" if summary["missing"] else "")
        + (
            f", {summary['draws_under_min_blur']} draws under --min-blur-px "
            f"{summary['min_blur_px']:g} drawn again"
            if summary["min_blur_px"]
            else ""
        )
    )
    return 0
