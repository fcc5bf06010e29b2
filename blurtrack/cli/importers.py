"""``blurtrack import {deepgyro,marslogger} SRC OUT``: third-party recordings to sessions."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from blurtrack.io.atomic import write_text_atomic


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="convert a third-party recording into a session folder")
    p.add_argument("kind", choices=["deepgyro", "marslogger"], help="source format")
    p.add_argument("src", type=Path, help="source folder")
    p.add_argument("out", type=Path, help="new session folder (must not exist or be empty)")
    p.add_argument(
        "--overlays",
        type=int,
        default=0,
        metavar="N",
        help="also draw predicted trajectories over the first N frames",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blurtrack.io.atomic import atomic_dir
    from blurtrack.io.guard import check_new_folder
    from blurtrack.io.importers import IMPORTERS
    from blurtrack.io.session import load_session
    from blurtrack.overlay import draw_session_overlays

    check_new_folder(args.out, "session folder")
    with atomic_dir(args.out) as tmp:  # a failure leaves no half session behind
        summary = IMPORTERS[args.kind](args.src, tmp)
    session = load_session(args.out)
    if args.overlays:
        n = min(args.overlays, len(session.frames))
        summary["overlays"] = draw_session_overlays(
            session, session.initial_calibration(), args.out / "overlays", list(range(n))
        )
    write_text_atomic(args.out / "summary.json", json.dumps(summary, indent=2))
    print(
        f"imported {summary['frames']} frames and {summary['gyro_samples']} gyro samples "
        f"from {args.src} into {args.out}"
    )
    for key, text in summary["assumptions"].items():
        print(f"  assumed {key}: {text}")
    if args.overlays:
        ov = summary["overlays"]
        print(f"  overlays: {len(ov['written'])} written to {args.out / 'overlays'}")
        for i, why in ov["skipped"].items():
            print(f"  frame {i} not drawn: {why}")
    return 0
