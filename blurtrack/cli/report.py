"""CLI command ``blurtrack report``: the endpoint-error report of a calibration."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from blurtrack.cli.progress import Progress, add_quiet_arg
from blurtrack.cli.report_inputs import load_calibrations, load_fit_summary
from blurtrack.cli.sources import add_streak_source_args, load_session_and_streaks
from blurtrack.io.guard import add_force_arg, check_output


def register(subparsers: Any) -> None:
    r = subparsers.add_parser("report", help="endpoint-error report of a calibration")
    r.add_argument("session", help="session folder")
    r.add_argument("--calib", required=True, help="calibration YAML to evaluate")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--before", help="calibration to compare with (default: session.yaml)")
    r.add_argument(
        "--fit-summary",
        help="summary JSON of the fit (default: the one written "
        "next to --calib by calibrate, if present)",
    )
    r.add_argument(
        "--overlays",
        type=int,
        default=3,
        help="frames drawn with their streaks (the worst by mean endpoint error)",
    )
    add_streak_source_args(r)
    add_quiet_arg(r)
    add_force_arg(r)
    r.set_defaults(func=run_report)


def run_report(args: argparse.Namespace) -> int:
    from blurtrack.io import streaks as streak_table
    from blurtrack.io.session import load_session
    from blurtrack.report.build import build_report

    check_output(args.out, folder=True, force=args.force)
    session = load_session(args.session)
    if session.meta.target_kind == "natural":
        from blurtrack.cli.report_natural import run_natural_report

        return run_natural_report(args, session)
    session, table = load_session_and_streaks(args)
    before, after = load_calibrations(args, session)
    streak_table.check_matches_session(table, session.frames, session.meta.camera.resolution)
    fit = load_fit_summary(args)
    with Progress("report", "step", args.quiet) as bar:
        summary = build_report(
            session,
            table,
            before,
            after,
            args.out,
            fit_summary=fit,
            n_overlays=args.overlays,
            progress=bar,
        )
    for k in ("before", "after"):
        s = summary["overall"][k]
        print(
            f"{k:>7}: mean {s['mean_px']:.3f} px, median {s['median_px']:.3f}, "
            f"p95 {s['p95_px']:.3f} ({s['n']} streaks)"
        )
    for k, s in summary["motion_models"].items():
        print(f"  {summary['motion_model_labels'][k]}: mean {s['mean_px']:.3f} px")
    fl = summary["flagged"]
    if fl["n_flagged"]:
        print(
            f"  {fl['n_flagged']} flagged streak(s) ({', '.join(fl['excluded_flags'])}) "
            "left out of the statistics"
        )
    for w in summary["warnings"]:
        print(f"warning: {w}")
    print(f"wrote {Path(args.out) / 'report.html'}")
    return 0
