"""``blurtrack import {deepgyro,marslogger,euroc,rosbag,video,frames} SRC OUT``: third-party
recordings to sessions (docs/interop.md)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from blurtrack.io.atomic import write_json_atomic


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="convert a third-party recording into a session folder")
    p.add_argument(
        "kind",
        choices=["deepgyro", "marslogger", "euroc", "rosbag", "video", "frames"],
        help="source format (frames: a folder of images, a frame-times file, a gyro CSV)",
    )
    p.add_argument("src", type=Path, help="source folder, bag (file or folder) or video file")
    p.add_argument("out", type=Path, help="new session folder (must not exist or be empty)")
    p.add_argument(
        "--exposure-ms",
        type=float,
        help="exposure per frame (euroc, rosbag, video: these sources do not record it)",
    )
    p.add_argument(
        "--readout-ms",
        type=float,
        help="rolling-shutter readout (euroc, rosbag: default 0 = global shutter; "
        "video: default the gcsv's frame_readout_time, else 0)",
    )
    p.add_argument(
        "--stamp",
        choices=["start", "middle"],
        help="what the source's frame stamps mark: start of exposure or its centre "
        "(euroc, rosbag, video; default: start)",
    )
    p.add_argument("--image-topic", help="rosbag: Image/CompressedImage topic (default: the one)")
    p.add_argument("--imu-topic", help="rosbag: Imu topic (default: the only one)")
    p.add_argument(
        "--calib",
        type=Path,
        help="rosbag: a Kalibr/BlurTrack calibration file for intrinsics and axes",
    )
    p.add_argument("--gcsv", type=Path, help="video: Gyroflow log (default: SRC with .gcsv)")
    p.add_argument(
        "--max-frames", type=int, help="euroc, rosbag, video, frames: import at most N frames"
    )
    p.add_argument("--images", type=Path, help="frames: the image folder (default: found in SRC)")
    p.add_argument(
        "--frame-times",
        type=Path,
        help="frames: one time per line (line k = frame k) or 'time,filename' rows "
        "(default: the one *frame*/*stamp*/*times* file in SRC)",
    )
    p.add_argument("--gyro", type=Path, help="frames: gyro CSV (default: the *gyro*/*imu* file)")
    p.add_argument(
        "--gyro-columns",
        help="frames: the gyro CSV's columns, e.g. wx,wy,wz,t or t,wx,wy,wz ('-' skips one; "
        "default: from the header, else the increasing column is time)",
    )
    p.add_argument(
        "--time-unit",
        choices=["s", "ms", "us", "ns"],
        help="frames: unit of frame and gyro times (default: detected from the intervals)",
    )
    p.add_argument(
        "--gyro-unit",
        choices=["rad/s", "deg/s"],
        help="frames: gyro unit (default rad/s, deg/s when a sample exceeds 35 rad/s)",
    )
    p.add_argument(
        "--intrinsics",
        help="frames: fx,fy,cx,cy in px (default: a stated guess, fx = fy = width)",
    )
    p.add_argument(
        "--turn-180",
        action="store_true",
        help="the sensor reads its bottom row first (mounted upside down; blurtrack detect "
        "says so): store every frame turned by 180 degrees, with the principal point and the "
        "camera axes turned alike, so that the rows read top first",
    )
    p.add_argument(
        "--overlays",
        type=int,
        default=0,
        metavar="N",
        help="also draw predicted trajectories over the first N frames",
    )
    p.set_defaults(func=run)


def importer_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The options given on the command line, as the chosen importer's keyword arguments;
    an option the importer does not take is refused."""
    from blurtrack.errors import ImportFormatError
    from blurtrack.io.importers import IMPORTER_OPTIONS

    given = {
        "exposure_s": None if args.exposure_ms is None else args.exposure_ms * 1e-3,
        "readout_s": None if args.readout_ms is None else args.readout_ms * 1e-3,
        "stamp": args.stamp,
        "image_topic": args.image_topic,
        "imu_topic": args.imu_topic,
        "calib": args.calib,
        "gcsv": args.gcsv,
        "max_frames": args.max_frames,
        "images": args.images,
        "frame_times_file": args.frame_times,
        "gyro": args.gyro,
        "gyro_columns": args.gyro_columns,
        "time_unit": args.time_unit,
        "gyro_unit": args.gyro_unit,
        "intrinsics": _intrinsics(args.intrinsics),
    }
    given = {k: v for k, v in given.items() if v is not None}
    allowed = IMPORTER_OPTIONS[args.kind]
    extra = sorted(k for k in given if k not in allowed)
    if extra:
        flags = ", ".join(OPTION_FLAGS[k] for k in extra)
        raise ImportFormatError(f"import {args.kind} does not take {flags}")
    if given.get("max_frames", 1) < 1:
        raise ImportFormatError("--max-frames must be at least 1")
    return given


OPTION_FLAGS = {
    "exposure_s": "--exposure-ms",
    "readout_s": "--readout-ms",
    "stamp": "--stamp",
    "image_topic": "--image-topic",
    "imu_topic": "--imu-topic",
    "calib": "--calib",
    "gcsv": "--gcsv",
    "max_frames": "--max-frames",
    "images": "--images",
    "frame_times_file": "--frame-times",
    "gyro": "--gyro",
    "gyro_columns": "--gyro-columns",
    "time_unit": "--time-unit",
    "gyro_unit": "--gyro-unit",
    "intrinsics": "--intrinsics",
}


def _intrinsics(text: str | None) -> tuple[float, float, float, float] | None:
    """``--intrinsics fx,fy,cx,cy`` as four numbers."""
    from blurtrack.errors import ImportFormatError

    if text is None:
        return None
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise ImportFormatError(f"--intrinsics must be fx,fy,cx,cy, got {text!r}") from None
    return fx, fy, cx, cy


#: Stamped on overlays drawn with a guessed camera-IMU axis mapping.
GUESS_LABEL = "axes UNKNOWN: drawn with the importer's guess, not a calibration"


def label_image(path: Path, text: str) -> None:
    """Stamp ``text`` in a dark band across the top of the image file at ``path``."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return
    scale = max(img.shape[1] / 1600.0, 0.4)
    band = int(40 * scale)
    img[:band] = (img[:band] * 0.3).astype(img.dtype)
    cv2.putText(
        img,
        text,
        (int(10 * scale), int(28 * scale)),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        (0, 255, 255),
        max(1, int(2 * scale)),
        cv2.LINE_AA,
    )
    cv2.imwrite(str(path), img)


def run(args: argparse.Namespace) -> int:
    from blurtrack.io.atomic import atomic_dir
    from blurtrack.io.guard import check_new_folder
    from blurtrack.io.importers import IMPORTERS
    from blurtrack.io.session import load_session
    from blurtrack.overlay import draw_session_overlays

    check_new_folder(args.out, "session folder")
    with atomic_dir(args.out) as tmp:  # a failure leaves no half session behind
        summary = IMPORTERS[args.kind](args.src, tmp, **importer_kwargs(args))
        if args.turn_180:
            from blurtrack.io.turn import turn_session_files

            summary["turned_180"] = turn_session_files(tmp)
    session = load_session(args.out)
    axes_known = session.meta.imu.axes_known
    summary["axes_known"] = axes_known
    if args.overlays:
        n = min(args.overlays, len(session.frames))
        summary["overlays"] = draw_session_overlays(
            session, session.initial_calibration(), args.out / "overlays", list(range(n))
        )
        if not axes_known:
            for path in summary["overlays"]["written"]:
                label_image(Path(path), GUESS_LABEL)
    write_json_atomic(args.out / "summary.json", summary)
    print(
        f"imported {summary['frames']} frames and {summary['gyro_samples']} gyro samples "
        f"from {args.src} into {args.out}"
    )
    for key, text in summary["assumptions"].items():
        print(f"  assumed {key}: {text}")
    if args.turn_180:
        print(
            f"  turned: {summary['turned_180']} frames by 180 degrees, the principal point and "
            "the camera axes with them (the rows now read top first)"
        )
    if not axes_known:
        print("  camera-IMU axes unknown: `blurtrack calibrate` searches the 24 signed axis maps")
    if args.overlays:
        ov = summary["overlays"]
        tag = " (labelled: drawn with the guessed axes)" if not axes_known else ""
        print(f"  overlays: {len(ov['written'])} written to {args.out / 'overlays'}{tag}")
        for i, why in ov["skipped"].items():
            print(f"  frame {i} not drawn: {why}")
    return 0
