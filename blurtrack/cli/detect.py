"""``blurtrack detect SESSION [--out FILE]``: the streak table of every frame."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.guard import add_force_arg, check_output


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
    add_force_arg(p)
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
    from blurtrack.detect.session import detect_session
    from blurtrack.detect.table import write_table
    from blurtrack.io.images import write_image
    from blurtrack.io.session import load_session

    cv2.setNumThreads(1)
    check_output(
        args.out,
        force=args.force,
        inputs=[args.params],
        siblings=[args.out.stem + ".summary.json"],
    )
    if args.overlay is not None:
        check_output(args.overlay, force=args.force, what="--overlay")
    session = load_session(args.session)
    params = DetectParams.from_yaml(args.params) if args.params else DetectParams()
    frames = _frame_range(args.frames, len(session.frames))
    result = detect_session(session, params, gyro=args.gyro, frames=frames)
    write_table(result.table, args.out)
    summary = dict(result.summary, session=str(args.session), table=str(args.out))
    if args.overlay is not None:
        first = int(result.table["frame"].iloc[0])
        pic = draw_streaks(session.read_image(first), result.table[result.table["frame"] == first])
        write_image(args.overlay, pic)
        summary["overlay"] = str(args.overlay)
    summary_path = args.out.with_name(args.out.stem + ".summary.json")
    write_json_atomic(summary_path, summary)
    s = result.summary
    print(f"detect: {s['streaks']} streaks in {s['frames']} frames -> {args.out}")
    print(
        f"  orientation: {s['orientation_sources']}, median confidence "
        f"{s['orientation_confidence_median']:.3f}"
    )
    print(f"  flags: {s['flags']}")
    if s["frames_without_streaks"]:
        print(
            f"  warning: {len(s['frames_without_streaks'])} frame(s) without streaks: "
            f"{s['frames_without_streaks'][:10]}",
            file=sys.stderr,
        )
    if s["frames_without_gyro"]:
        print(
            f"  warning: gyro does not cover {len(s['frames_without_gyro'])} frame(s); "
            "their orientation is image-only",
            file=sys.stderr,
        )
    return 0
