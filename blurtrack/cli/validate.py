"""``blurtrack validate SESSION``: decode all frames, check gyro coverage, fail on errors."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check a session folder thoroughly")
    p.add_argument("session", type=Path)
    p.add_argument(
        "--max-gyro-gap-ms",
        type=float,
        default=None,
        help="longest gyro gap that counts as covered (default: 5 sample intervals)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blurtrack.io.validate import validate_session

    gap = None if args.max_gyro_gap_ms is None else args.max_gyro_gap_ms * 1e-3
    rep = validate_session(args.session, gap)
    s = rep.session
    print(
        f"{args.session}: {len(s.frames)} frames, {s.imu_t_ns.size} gyro samples, "
        f"{rep.frames_covered} frames covered by the gyro"
    )
    for w in rep.warnings:
        print(f"  warning: {w}")
    for e in rep.errors:
        print(f"  error: {e}")
    if not rep.ok:  # the one line on stderr of every command that fails
        print(
            f"blurtrack validate: {len(rep.errors)} error(s) in {args.session} (listed on stdout)",
            file=sys.stderr,
        )
    return 0 if rep.ok else 1
