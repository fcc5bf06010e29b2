"""``blurtrack report`` on a natural-scene session (CLI layer of
:mod:`blurtrack.report.natural`; dispatched from :mod:`blurtrack.cli.report`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from blurtrack.cli.progress import Progress
from blurtrack.cli.report_inputs import load_calibrations, load_fit_summary


def run_natural_report(args: argparse.Namespace, session: Any) -> int:
    from blurtrack.errors import BlurTrackError
    from blurtrack.report.natural import build_natural_report

    if args.streaks or args.from_truth:
        raise BlurTrackError("--streaks and --from-truth apply to laser sessions")
    before, after = load_calibrations(args, session)
    fit = load_fit_summary(args)
    with Progress("report", "frame pair", args.quiet) as bar:
        summary = build_natural_report(session, before, after, args.out, fit, progress=bar)
    nat = summary["natural"]
    for k in ("before", "after"):
        s = nat["track_errors"][k]
        a = nat["agreement"][k]
        print(
            f"{k:>7}: track error mean {s['mean_px']:.3f} px, median {s['median_px']:.3f} "
            f"({s['n']} tracks); registered vs gyro rotation median {a['median_deg']:.4f} deg"
        )
    if nat.get("axes"):
        print(f"  axis search margin {nat['axes']['margin']:.2f} (winner of 24)")
    for w in summary["warnings"]:
        print(f"warning: {w}")
    print(f"wrote {Path(args.out) / 'report.html'}")
    return 0
