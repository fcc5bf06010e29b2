"""What ``blurtrack report`` reads besides the session: the calibrations to compare and the
fit's summary (used by :mod:`blurtrack.cli.report` and :mod:`blurtrack.cli.report_natural`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from blurtrack.cli.sources import summary_path


def load_calibrations(args: argparse.Namespace, session: Any) -> tuple[Any, Any]:
    """The calibrations to compare (``--before``, default the session's own, and ``--calib``),
    each checked to be for the session's frame size."""
    from blurtrack.errors import BlurTrackError
    from blurtrack.io.calibration import read_calibration

    after = read_calibration(args.calib)
    before = read_calibration(args.before) if args.before else session.initial_calibration()
    want = tuple(session.meta.camera.resolution)
    for name, cal in (("--calib", after), ("--before", before)):
        if tuple(cal.camera.resolution) != want:
            raise BlurTrackError(
                f"{name} is a calibration for {cal.camera.resolution[0]}x"
                f"{cal.camera.resolution[1]} frames; {args.session} has {want[0]}x{want[1]}"
            )
    return before, after


def load_fit_summary(args: argparse.Namespace) -> dict[str, Any] | None:
    """The fit summary: ``--fit-summary``, else the one calibrate wrote next to ``--calib``
    if present (None when there is none)."""
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
