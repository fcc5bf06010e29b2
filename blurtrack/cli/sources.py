"""Where ``calibrate`` and ``report`` take their streaks from, and where fit summaries live."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_streak_source_args(p: argparse.ArgumentParser) -> None:
    """``--streaks FILE`` or ``--from-truth``, shared by calibrate and report."""
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--streaks",
        help="streak table (default: SESSION/streaks.parquet, detected first with default "
        "parameters when it does not exist)",
    )
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
    elif args.streaks:
        table = streak_table.read(Path(args.streaks))
    else:
        path = Path(args.session) / "streaks.parquet"
        if path.is_file():
            table = streak_table.read(path)
        elif session.meta.target_kind != "laser-grid":
            raise BlurTrackError(
                f"{path} does not exist and a {session.meta.target_kind!r} session has no "
                "laser streaks to detect"
            )
        else:
            table = _detect_first(session, path, bool(getattr(args, "quiet", False)))
    return session, table


def _detect_first(session: Any, path: Path, quiet: bool) -> Any:
    """Run ``blurtrack detect`` (default parameters) into the session's ``streaks.parquet``."""
    from blurtrack.cli.detect import detect_summary_path, detect_to_table
    from blurtrack.io.atomic import write_json_atomic
    from blurtrack.io.guard import check_output

    summary_path = detect_summary_path(path, session.folder)
    check_output(path, force=True, what="the streak table")  # the guard's place checks
    check_output(summary_path, force=True, what="the detection summary")

    print(
        f"no streak table at {path}: detecting the streaks first "
        f"(as `blurtrack detect {session.folder}`)"
    )  # stdout: stderr holds only the one line of a failure
    result = detect_to_table(session, path, quiet=quiet)
    summary = dict(result.summary, session=str(session.folder), table=str(path))
    write_json_atomic(summary_path, summary)
    print(
        f"detect: {result.summary['streaks']} streaks in {result.summary['frames']} frames "
        f"-> {path}"
    )
    return result.table


def summary_path(calib_path: str | Path) -> Path:
    """The fit summary beside a calibration file (``calib.yaml`` -> ``calib.summary.json``)."""
    p = Path(calib_path)
    return p.with_name(p.stem + ".summary.json")
