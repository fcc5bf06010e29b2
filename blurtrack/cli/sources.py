"""Where ``calibrate`` and ``report`` take their streaks from, and where fit summaries live."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_streak_source_args(p: argparse.ArgumentParser) -> None:
    """``--streaks FILE`` or ``--from-truth``, shared by calibrate and report."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--streaks", help="streak table (default: SESSION/streaks.parquet)")
    g.add_argument(
        "--from-truth",
        action="store_true",
        help="use the simulator's true streaks (truth.yaml) instead of detections",
    )


def load_session_and_streaks(args: argparse.Namespace) -> tuple[Any, Any]:
    """The session and its streak table as ``--streaks``/``--from-truth`` choose."""
    from blurtrack.errors import BlurTrackError
    from blurtrack.io import streaks as streak_table
    from blurtrack.io.session import load_session

    session = load_session(args.session)
    if args.from_truth:
        if session.truth is None:
            raise BlurTrackError(f"--from-truth: {args.session} has no truth.yaml")
        table = streak_table.from_truth(session.truth)
    else:
        path = Path(args.streaks) if args.streaks else Path(args.session) / "streaks.parquet"
        table = streak_table.read(path)
    return session, table


def summary_path(calib_path: str | Path) -> Path:
    """The fit summary beside a calibration file (``calib.yaml`` -> ``calib.summary.json``)."""
    p = Path(calib_path)
    return p.with_name(p.stem + ".summary.json")
