"""``blurtrack export rosbag SESSION OUT``: a session as a ROS bag (Kalibr, OpenVINS, ROS 2)."""

from __future__ import annotations

import argparse
from pathlib import Path

from blurtrack.cli.progress import add_quiet_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a session in another tool's format (ROS bag)")
    p.add_argument("format", choices=["rosbag"], help="output format")
    p.add_argument("session", type=Path, help="session folder")
    p.add_argument("out", type=Path, help="new .bag file (ROS 1) or bag folder (--ros2)")
    p.add_argument(
        "--ros2", action="store_true", help="write a ROS 2 bag folder (default: a ROS 1 .bag)"
    )
    p.add_argument(
        "--storage",
        choices=["mcap", "sqlite3"],
        default="mcap",
        help="ROS 2 storage plugin (default: %(default)s)",
    )
    p.add_argument(
        "--stamp",
        choices=["start", "middle"],
        default="start",
        help="header stamps at the start of the top row's exposure or at the frame's exposure "
        "centre (default: %(default)s)",
    )
    add_quiet_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blurtrack.cli.progress import Progress
    from blurtrack.io.guard import check_output
    from blurtrack.io.rosbag_export import (
        ExportError,
        export_rosbag,
        kalibr_companions,
        write_kalibr_companions,
    )
    from blurtrack.io.session import load_session

    if args.storage != "mcap" and not args.ros2:
        raise ExportError("--storage applies to ROS 2 bags only (add --ros2)")
    check_output(
        args.out,
        folder=args.ros2,
        what="OUT",
        siblings=[p.name for p in kalibr_companions(args.out)],
        input_folders=[args.session],
    )
    if args.ros2 and args.out.exists():  # rosbags writes a new folder only
        raise ExportError(f"OUT {str(args.out)!r} exists; a ROS 2 bag is written as a new folder")
    session = load_session(args.session)
    total = len(session.frames)
    with Progress("export", "frame", args.quiet) as bar:
        done = [0]

        def step() -> None:
            done[0] += 1
            bar(done[0], total)

        summary = export_rosbag(
            session,
            args.out,
            ros2=args.ros2,
            storage=args.storage,
            stamp=args.stamp,
            progress=step,
        )
    try:
        files = write_kalibr_companions(session, args.out)
    except BaseException:  # no bag without its Kalibr files: a rerun starts clean
        _remove(args.out)
        for p in kalibr_companions(args.out):
            p.unlink(missing_ok=True)
        raise
    topics = ", ".join(summary["topics"])
    print(
        f"wrote {summary['format']} {args.out}: {summary['frames']} frames "
        f"({'/'.join(summary['encodings']) or 'none'}), {summary['imu_samples']} IMU samples; "
        f"topics {topics}; stamps at the {summary['stamp']} of exposure"
    )
    print(f"  Kalibr inputs: --cams {files['camchain']} --imu {files['imu']}")
    print(f"  IMU noise from {files['imu_noise_source']}")
    if not summary["accelerometer"]:
        print("  no accelerometer in the session: /imu0 marks linear_acceleration unknown "
              "(Kalibr's camera-IMU calibration needs it)")  # fmt: skip
    return 0


def _remove(path: Path) -> None:
    import shutil

    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
