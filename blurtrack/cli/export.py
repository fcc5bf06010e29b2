"""``blurtrack export rosbag SESSION OUT``: a session as a ROS bag (Kalibr, OpenVINS, ROS 2)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from blurtrack.io.rosbag_export import (
        ExportError,
        export_rosbag,
        kalibr_companions,
        write_kalibr_companions,
    )
    from blurtrack.io.session import load_session

    if args.storage != "mcap" and not args.ros2:
        raise ExportError("--storage applies to ROS 2 bags only (add --ros2)")
    session = load_session(args.session)
    for p in kalibr_companions(args.out):
        if p.exists():
            raise ExportError(f"refusing to overwrite {p}")
    with tqdm(total=len(session.frames), unit="frame", desc="export", file=sys.stderr) as bar:
        summary = export_rosbag(
            session,
            args.out,
            ros2=args.ros2,
            storage=args.storage,
            stamp=args.stamp,
            progress=lambda: bar.update(1),
        )
    topics = ", ".join(summary["topics"])
    print(
        f"wrote {summary['format']} {args.out}: {summary['frames']} frames "
        f"({'/'.join(summary['encodings']) or 'none'}), {summary['imu_samples']} IMU samples; "
        f"topics {topics}; stamps at the {summary['stamp']} of exposure"
    )
    files = write_kalibr_companions(session, args.out)
    print(f"  Kalibr inputs: --cams {files['camchain']} --imu {files['imu']}")
    print(f"  IMU noise from {files['imu_noise_source']}")
    if not summary["accelerometer"]:
        print("  no accelerometer in the session: /imu0 marks linear_acceleration unknown "
              "(Kalibr's camera-IMU calibration needs it)")  # fmt: skip
    return 0
