"""``blurtrack predict``: per-frame heat maps and trajectories of a recording."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from blurtrack.cli.progress import Progress, add_quiet_arg
from blurtrack.io.guard import add_force_arg, check_output


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "predict",
        help="per-frame blur heat maps and trajectories of a recording",
        description="Predict every frame's blur trajectories from the session's gyro and a "
        "calibration: DIR/heat/<timestamp_ns>.npy (6, H, W) float32, "
        "DIR/trajectories.parquet, DIR/summary.json.",
    )
    p.add_argument("session", help="session folder")
    p.add_argument("--calib", required=True, help="calibration file")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--stride", type=int, default=8, help="heat-map evaluation stride (px)")
    p.add_argument("--samples", type=int, default=16, help="trajectory samples per pixel")
    p.add_argument("--grid", default="16x9", help="trajectory table grid, NXxNY nodes")
    p.add_argument(
        "--skip-uncovered",
        action="store_true",
        help="skip frames the gyro does not cover instead of refusing",
    )
    p.add_argument(
        "--overlays",
        type=int,
        default=0,
        metavar="N",
        help="also draw the predicted trajectories over the first N frames (overlays/)",
    )
    add_quiet_arg(p)
    add_force_arg(p)
    p.set_defaults(func=run)


def _overlays(session: Any, calib: Any, out: Path, n: int) -> dict[str, object]:
    """Overlays of the first ``n`` frames in ``out/overlays``, stamped when ``calib`` is
    partial."""
    from blurtrack.cli.importers import label_image
    from blurtrack.overlay import draw_session_overlays

    drawn = draw_session_overlays(
        session, calib, out / "overlays", list(range(min(n, len(session.frames))))
    )
    if calib.partial is not None:
        stamp = f"PARTIAL: {calib.partial.get('decided', 'not fitted')} only; fit refused"
        for path in drawn["written"]:  # type: ignore[attr-defined]
            label_image(Path(path), stamp)
    return drawn


def run(args: argparse.Namespace) -> int:
    from blurtrack.errors import SynthesisError
    from blurtrack.io.atomic import write_json_atomic
    from blurtrack.io.bounds import check_prediction_size
    from blurtrack.io.calibration import read_calibration
    from blurtrack.io.session import load_session
    from blurtrack.synth.predict import predict_session

    try:
        gx, gy = (int(v) for v in args.grid.lower().split("x"))
    except ValueError:
        raise SynthesisError(f"--grid must be NXxNY, got {args.grid!r}") from None
    if gx < 2 or gy < 2 or args.stride < 1 or args.samples < 3:
        raise SynthesisError("--grid needs >= 2 nodes per axis, --stride >= 1, --samples >= 3")
    if args.overlays < 0:
        raise SynthesisError(f"--overlays must be 0 or more, got {args.overlays}")
    check_output(args.out, folder=True, force=args.force)
    session = load_session(args.session)
    calib = read_calibration(args.calib)
    check_prediction_size(*calib.camera.resolution, args.stride, args.samples)
    if calib.partial_label is not None:
        print(f"predict: {calib.partial_label}")
    with Progress("predict", "frame", args.quiet) as bar:
        res = predict_session(
            session,
            calib,
            args.out,
            args.stride,
            args.samples,
            (gx, gy),
            args.skip_uncovered,
            bar,
        )
    summary = {
        "command": "predict",
        "session": str(args.session),
        "calib": str(args.calib),
        "partial": calib.partial,
        **res.stats,
        "skipped_timestamps_ns": res.skipped,
    }
    if args.overlays:
        summary["overlays"] = _overlays(session, calib, Path(args.out), args.overlays)
    write_json_atomic(Path(args.out) / "summary.json", summary)
    fit = res.stats["bezier_fit_within_0.5px"]
    print(
        f"predict: {len(res.written)} of {res.stats['frames']} frames -> {args.out} "
        f"(Bezier fit within 0.5 px: {100 * fit:.2f} %"
        + (f", {len(res.skipped)} skipped: gyro does not cover them" if res.skipped else "")
        + ")"
    )
    return 0
