"""``blurtrack detect SESSION [--out FILE]``: the streak table of every frame."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "detect",
        help="detect laser-dot streaks and write the streak table (Parquet)",
        description="Find every laser-dot streak in every frame of a session: sub-pixel "
        "start and end, centre line, brightness profile, quality flags; start/end resolved "
        "with the gyro (initial guesses), continuity and brightness.",
    )
    p.add_argument("session", type=Path, help="session folder")
    p.add_argument(
        "--out",
        type=Path,
        default=Path("streaks.parquet"),
        help="output table (Parquet; default ./streaks.parquet); a summary is "
        "written beside it as <stem>.summary.json",
    )
    p.add_argument(
        "--gyro",
        choices=("auto", "on", "off"),
        default="auto",
        help="use the gyro to tell start from end: auto (where it covers the "
        "frame), on (required), off (image only)",
    )
    p.add_argument("--params", type=Path, default=None, help="detection parameters (YAML)")
    p.add_argument(
        "--frames", default=None, metavar="A:B", help="only frames A..B-1 (Python slice syntax)"
    )
    p.add_argument(
        "--overlay",
        type=Path,
        default=None,
        metavar="PNG",
        help="also draw the detected streaks over the first frame with streaks",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="processes that decode and detect frames in parallel (default: the CPU cores; "
        "the table does not depend on it)",
    )
    p.set_defaults(func=run)


def _frame_range(text: str | None, n: int) -> range | None:
    from blurtrack.errors import DetectionError

    if text is None:
        return None
    try:
        a, _, b = text.partition(":")
        return range(n)[slice(int(a) if a else None, int(b) if b else None)]
    except ValueError:
        raise DetectionError(f"--frames must look like A:B, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    import cv2

    from blurtrack.detect import DetectParams
    from blurtrack.detect.overlay import draw_streaks
    from blurtrack.detect.session import default_workers, detect_session
    from blurtrack.detect.table import write_table
    from blurtrack.errors import DetectionError
    from blurtrack.io.session import load_session

    cv2.setNumThreads(1)
    session = load_session(args.session)
    params = DetectParams.from_yaml(args.params) if args.params else DetectParams()
    frames = _frame_range(args.frames, len(session.frames))
    workers = default_workers() if args.workers is None else args.workers
    result = detect_session(session, params, gyro=args.gyro, frames=frames, workers=workers)
    write_table(result.table, args.out)
    summary = dict(result.summary, session=str(args.session), table=str(args.out))
    if args.overlay is not None:
        first = int(result.table["frame"].iloc[0])
        pic = draw_streaks(session.read_image(first), result.table[result.table["frame"] == first])
        args.overlay.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.overlay), pic):
            raise DetectionError(f"cannot write overlay picture {args.overlay}")
        summary["overlay"] = str(args.overlay)
    summary_path = args.out.with_name(args.out.stem + ".summary.json")
    summary_path.write_text(json.dumps(summary, indent=2))
    s = result.summary
    print(f"detect: {s['streaks']} streaks in {s['frames']} frames -> {args.out}")
    print(
        f"  orientation: {s['orientation_sources']}, median confidence "
        f"{s['orientation_confidence_median']:.3f}"
    )
    print(f"  flags: {s['flags']}")
    if s["gyro_timeshift_status"] == "found":
        print(f"  camera-IMU time shift: {1e3 * s['gyro_timeshift_s']:+.2f} ms (coarse scan)")
    elif s["gyro_timeshift_status"] != "no gyro":
        print(f"  camera-IMU time shift: {s['gyro_timeshift_status']}")
    if s["frames_without_streaks"]:
        print(
            f"  warning: {len(s['frames_without_streaks'])} frame(s) without streaks: "
            f"{s['frames_without_streaks'][:10]}",
            file=sys.stderr,
        )
    if s["frames_overexposed"]:
        print(
            f"  warning: {len(s['frames_overexposed'])} over-exposed frame(s) (mostly "
            f"saturated): {s['frames_overexposed'][:10]}",
            file=sys.stderr,
        )
    if s["frames_without_gyro"]:
        print(
            f"  warning: gyro does not cover {len(s['frames_without_gyro'])} frame(s); "
            "their orientation is image-only",
            file=sys.stderr,
        )
    return 0
