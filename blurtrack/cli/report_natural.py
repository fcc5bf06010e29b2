"""``blurtrack report`` on a natural-scene session (CLI layer of
:mod:`blurtrack.report.natural`; dispatched from :mod:`blurtrack.cli.report`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from blurtrack.cli.progress import Progress
from blurtrack.cli.sources import summary_path


def _fit_summary(args: argparse.Namespace) -> dict[str, Any] | None:
    from blurtrack.errors import BlurTrackError

    path = Path(args.fit_summary) if args.fit_summary else summary_path(args.calib)
    if not path.is_file():
        if args.fit_summary:
            raise BlurTrackError(f"fit summary not found: {path}")
        return None
    try:
        fit = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BlurTrackError(f"fit summary {path} is not valid JSON ({exc})") from None
    if not isinstance(fit, dict):
        raise BlurTrackError(f"fit summary {path} is not a JSON object")
    return fit


def run_natural_report(args: argparse.Namespace, session: Any) -> int:
    from blurtrack.errors import BlurTrackError
    from blurtrack.io.calibration import Calibration
    from blurtrack.report.natural import build_natural_report

    if args.streaks or args.from_truth:
        raise BlurTrackError("--streaks and --from-truth apply to laser sessions")
    after = Calibration.from_yaml(args.calib)
    before = Calibration.from_yaml(args.before) if args.before else session.initial_calibration()
    want = tuple(session.meta.camera.resolution)
    for name, cal in (("--calib", after), ("--before", before)):
        if tuple(cal.camera.resolution) != want:
            raise BlurTrackError(
                f"{name} is a calibration for {cal.camera.resolution[0]}x"
                f"{cal.camera.resolution[1]} frames; {args.session} has {want[0]}x{want[1]}"
            )
    fit = _fit_summary(args)
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
