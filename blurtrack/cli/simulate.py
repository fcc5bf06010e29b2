"""``blurtrack simulate OUT``: a simulated laser-grid session with its truth (rigs.sim)."""

from __future__ import annotations

import argparse
from pathlib import Path

from blurtrack.cli.progress import Progress, add_quiet_arg
from blurtrack.errors import BlurTrackError
from blurtrack.io.atomic import write_json_atomic


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="render a simulated laser-grid session (with truth.yaml)",
        description="Render a simulated laser-grid recording: frames, gyro, session.yaml (the "
        "rig's nominal guesses) and truth.yaml (true calibration and streaks).",
    )
    p.add_argument("out", type=Path, help="session folder to create (must not exist or be empty)")
    p.add_argument(
        "--preset", default="realistic", help="built-in preset: clean, realistic (default) or hard"
    )
    p.add_argument(
        "--preset-file",
        type=Path,
        default=None,
        help="YAML preset (all keys optional; 'base: NAME' starts from a built-in)",
    )
    p.add_argument("--frames", type=int, default=100, help="number of frames (default 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--shake",
        type=Path,
        default=None,
        help="GyroDeblurNet shake trace for 'motion: shake' presets (default: "
        "../shared/data/real/gyrodeblurnet-shake/gyro_train.txt)",
    )
    p.add_argument(
        "--motion",
        choices=("synthetic", "shake"),
        default=None,
        help="override the preset's motion source",
    )
    p.add_argument(
        "--bit-depth",
        type=int,
        choices=(8, 16),
        default=None,
        help="override the preset's output bit depth",
    )
    p.add_argument("--imu-rate", type=float, default=None, help="override the gyro rate (Hz)")
    add_quiet_arg(p)
    p.add_argument(
        "--target",
        choices=("laser-grid", "natural"),
        default="laser-grid",
        help="what the camera films: the laser-dot grid or a natural scene (a "
        "BSDS500 photograph on a far plane, rigs.sim.natural)",
    )
    p.add_argument(
        "--background",
        type=Path,
        default=None,
        help="photograph for --target natural (default: one of "
        "../shared/data/backgrounds/bsds500/val chosen by the seed)",
    )
    p.add_argument(
        "--depth-m",
        type=float,
        default=None,
        help="--target natural: the photograph on a plane this far away (default: at infinity)",
    )
    p.add_argument(
        "--speed-mps",
        type=float,
        default=0.0,
        help="--target natural: drive towards the plane at this speed (needs --depth-m)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="render frames in this many processes (default 1; the session is identical "
        "for any number)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blurtrack.io.atomic import atomic_dir
    from blurtrack.io.bounds import check_simulate_size
    from blurtrack.io.guard import check_new_folder
    from rigs.sim.preset import SimPreset, get_preset
    from rigs.sim.rig import SimRig
    from rigs.sim.writer import write_session

    preset = SimPreset.from_yaml(args.preset_file) if args.preset_file else get_preset(args.preset)
    changes = {
        k: v
        for k, v in (
            ("motion", args.motion),
            ("bit_depth", args.bit_depth),
            ("imu_rate_hz", args.imu_rate),
        )
        if v is not None
    }
    if changes:
        preset = preset.replace(**changes)
    out = check_new_folder(args.out)
    check_simulate_size(preset.width, preset.height, args.workers)
    rig: SimRig
    if args.target == "natural":
        from rigs.sim.natural import NaturalRig

        rig = NaturalRig(
            preset,
            args.seed,
            args.frames,
            shake=args.shake,
            background=args.background,
            depth_m=args.depth_m,
            speed_mps=args.speed_mps,
        )
    else:
        if args.background is not None or args.depth_m is not None or args.speed_mps:
            raise BlurTrackError(
                "--background, --depth-m and --speed-mps apply to --target natural only"
            )
        rig = SimRig(preset, args.seed, args.frames, shake=args.shake)
    with Progress("simulate", "frame", args.quiet) as bar, atomic_dir(out) as tmp:
        # a failure (full disk, Ctrl-C) leaves no half session
        summary = dict(
            write_session(rig, tmp, progress=bar, workers=args.workers), session=str(out)
        )
    write_json_atomic(out / "summary.json", summary)
    t = summary["true"]
    print(f"simulated {summary['frames']} frames ({preset.name}, seed {args.seed}) into {out}")
    print(
        f"  streaks: {summary['streaks']} ({summary['streaks_inside']} inside), median "
        f"length {summary['streak_length_px']['median']:.1f} px, max "
        f"{summary['streak_length_px']['max']:.1f} px"
    )
    print(
        f"  true fx {t['intrinsics'][0]:.2f} px, readout {1e3 * t['readout_s']:.2f} ms, "
        f"offset {1e3 * t['timeshift_cam_imu_s']:+.2f} ms, gyro {summary['imu_samples']} "
        f"samples; {summary['seconds']['total']:.1f} s"
    )
    return 0
