"""CLI command ``blurtrack calibrate`` (listed in blurtrack.cli)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from blurtrack.cli.sources import add_streak_source_args, load_session_and_streaks
from blurtrack.io.guard import add_force_arg, check_output, output_lock
from calib.output import write_results, write_summary
from calib.params import DEFAULT_FIT
from calib.truth import truth_values

#: Display scale and unit of each parameter in the printed table.
_SHOW = {
    "timeshift_s": (1e3, "ms"),
    "readout_s": (1e3, "ms"),
    "fx": (1, "px"),
    "fy": (1, "px"),
    "cx": (1, "px"),
    "cy": (1, "px"),
    "bias_x": (1e3, "mrad/s"),
    "bias_y": (1e3, "mrad/s"),
    "bias_z": (1e3, "mrad/s"),
    "rot_x": (57.29577951308232, "deg"),
    "rot_y": (57.29577951308232, "deg"),
    "rot_z": (57.29577951308232, "deg"),
    **{f"scale_{a}": (1e3, "1e-3") for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
}


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("calibrate", help="fit the gyro blur model to a session's streaks")
    p.add_argument("session", help="session folder")
    p.add_argument("--out", required=True, help="calibration YAML to write (Kalibr keys)")
    p.add_argument(
        "--fit",
        default=DEFAULT_FIT,
        help="comma-separated parameter groups to estimate, from timeshift, fx, fy, "
        "cx, cy, readout, bias, rotation, scale (the gyro's symmetric scale / "
        "cross-axis error, written as gyro_scale_matrix; without it a score "
        f"test warns when the data ask for one); default: {DEFAULT_FIT}",
    )
    add_streak_source_args(p)
    p.add_argument(
        "--holdout",
        type=float,
        default=0.2,
        help="fraction of frames held out for evaluation (default 0.2)",
    )
    p.add_argument(
        "--shift-window-ms",
        type=float,
        default=60.0,
        help="half-width of the initial time-shift search (default 60 ms)",
    )
    p.add_argument(
        "--centreline",
        action="store_true",
        help="also fit the streaks' centre lines (point-to-track distances of a few "
        "points per streak, together weighing as one endpoint coordinate)",
    )
    p.add_argument(
        "--frame-noise",
        action="store_true",
        help="refine by generalised least squares under a per-frame gyro-noise "
        "model (rate offset and drift per frame): sharper principal point and "
        "focal lengths when gyro noise dominates, about 1.5x the time",
    )
    p.add_argument(
        "--residuals",
        choices=("auto", "endpoints", "tracks", "both"),
        default="auto",
        help="what the final stage fits: each streak's end predicted from its "
        "start (endpoints), each dot's time midpoint carried to the next frame "
        "(tracks: insensitive to biased streak ends), or both; auto (default): "
        "tracks where the streak table has midpoints and consecutive frames "
        "see the same dots, else endpoints with a warning",
    )
    add_force_arg(p)
    p.add_argument(
        "--target",
        choices=("auto", "laser-grid", "natural"),
        default="auto",
        help="what the frames show: laser-grid streaks, or a natural scene (feature tracks "
        "between frames); auto (default): session.yaml's target.kind",
    )
    p.add_argument(
        "--axes",
        choices=("search", "session"),
        default="search",
        help="camera-IMU axes: search (default) scores the 24 signed axis permutations "
        "against the images and starts from the winner (refusing an ambiguous one); session "
        "keeps session.yaml's T_cam_imu",
    )
    from calib.natural.cli import add_natural_args

    add_natural_args(p)
    p.set_defaults(func=run_calibrate)


def run_calibrate(args: argparse.Namespace) -> int:
    from calib.natural.cli import is_natural, run_natural

    stem = Path(args.out).stem
    check_output(
        args.out,
        force=args.force,
        # the streak table calibrate reads (detecting first when it is missing) is an input
        inputs=[args.streaks or Path(args.session) / "streaks.parquet"],
        siblings=[
            stem + s
            for s in (
                ".summary.json",
                ".openvins.yaml",
                ".camera_info.yaml",
                ".failed.summary.json",
                ".partial.yaml",
            )
        ],
    )
    with output_lock(args.out):  # two runs never write one calibration
        if is_natural(args):
            return run_natural(args, _print_table)
        return _calibrate_laser(args)


def refuse_bottom_first(args: argparse.Namespace, session: Any) -> None:
    """Stop (:class:`~calib.errors.CalibError`) where the streak table's detection summary says
    the frames read their bottom row first (``gyro_readout_order``,
    :mod:`blurtrack.detect.gyro.readout`): the blur model reads the top row first, and its
    readout, bounded at 0, cannot follow, so the fit would be wrong without saying so. No
    summary (a table from elsewhere, ``--from-truth``): nothing to check."""
    import json

    from blurtrack.cli.detect import detect_summary_path
    from calib.errors import CalibError

    if getattr(args, "from_truth", False):
        return
    table = Path(args.streaks) if args.streaks else Path(args.session) / "streaks.parquet"
    path = detect_summary_path(table, Path(session.folder))
    if not path.is_file():
        return
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibError(f"{path}: unreadable detection summary ({exc})") from None
    order = summary.get("gyro_readout_order") if isinstance(summary, dict) else None
    if isinstance(order, dict) and order.get("status") == "bottom_first":
        llr = order.get("llr_top_first")
        odds = f", log-likelihood ratio {llr:.0f}" if isinstance(llr, int | float) else ""
        raise CalibError(
            f"{path}: the frames read their bottom row first (detection's readout order"
            f"{odds}); calibrate models the top "
            "row first: import the recording again with --turn-180 (every frame turned by 180 "
            "degrees, the principal point and T_cam_imu with them), then detect and calibrate"
        )


def _calibrate_laser(args: argparse.Namespace) -> int:
    from calib.centreline import CENTRE_POINTS
    from calib.data import streaks_from_table
    from calib.fit import FitOptions, calibrate, check_fit_inputs
    from calib.natural.cli import laser_axes
    from calib.params import theta_from
    from calib.result import named

    if args.mask:
        from calib.errors import CalibError

        raise CalibError("--mask applies to natural-scene sessions (feature tracks)")
    session, table = load_session_and_streaks(args)
    refuse_bottom_first(args, session)
    streaks = streaks_from_table(
        table, session.frames, centre_k=CENTRE_POINTS if args.centreline else 0
    )
    if streaks.dropped_quality:
        print(
            f"calibrate: left out {streaks.dropped_quality} streaks that detection marked "
            "not quality_ok"
        )
    initial = session.initial_calibration()
    options = FitOptions(
        fit=args.fit,
        holdout_fraction=args.holdout,
        shift_window_s=args.shift_window_ms * 1e-3,
        centreline=args.centreline,
        frame_noise=args.frame_noise,
        residuals=args.residuals,
    )
    check_fit_inputs(streaks, options)  # bad input fails alone, before the axis search speaks
    axes, initial = laser_axes(args, streaks, session, initial)
    res = calibrate(streaks, session.gyro(), initial, options, progress=_render_progress)
    summary = res.to_dict()
    summary["options"] = dataclasses.asdict(options)
    summary["initial"] = named(theta_from(initial))
    if axes is not None:
        summary["axes"] = axes
    truth = truth_values(session, initial)
    if truth is not None:
        summary["truth"] = truth
        summary["error_vs_truth"] = {k: res.values[k] - truth[k] for k in res.values}
    out = Path(args.out)
    details = write_summary(res, summary, out)
    _print_table(res, summary.get("initial", {}), truth)
    print(write_results(res, out, details))
    return 0


def _render_progress(p: Any) -> None:
    """One line per stage start and LM iteration on stderr (:class:`calib.fit.Progress`),
    on a terminal only: in logs and pipes stderr holds nothing but a failure's one line."""
    from blurtrack.cli.progress import enabled

    if not enabled():
        return

    what = "starts" if p.iteration == 0 else f"iteration {p.iteration}, cost {p.cost:.6g}"
    print(f"calibrate: {p.stage}: {what} ({p.elapsed_s:.1f} s)", file=sys.stderr, flush=True)


def cell(value: float, width: int) -> str:
    """``value`` right-aligned in ``width`` characters with at least one space before it:
    four decimals where they fit, else four significant digits (``2.473e+08``).

    >>> cell(247.2631, 12) + cell(99338.9141, 11)
    '    247.2631 99338.9141'
    >>> cell(6.2e8, 11)
    '  6.200e+08'
    """
    text = f"{value:.4f}"
    if len(text) > width - 1:
        text = f"{value:.3e}"
    return " " + text.rjust(width - 1)


def _print_table(res: Any, initial: dict[str, float], truth: dict[str, float] | None) -> None:
    if res.holdout_fit_values is not None:
        print(
            "written: the refit on every frame; hold-out errors below are of the fit on "
            "the training frames"
        )
    print(
        f"calibration {res.status}: {res.iterations} iterations, "
        f"{res.train.n} inlier streaks, {res.n_outliers} outliers "
        f"({res.n_flipped} wrongly oriented), {res.timings_s.get('total', 0):.1f} s"
    )
    if res.tracks is not None:
        print(
            f"fitted {res.residuals}: {res.n_tracks} inter-frame tracks "
            f"({res.n_track_outliers} outliers), track error mean {res.tracks.mean_px:.3f} "
            f"px, median {res.tracks.median_px:.3f}, p95 {res.tracks.p95_px:.3f}"
        )
    else:
        print(f"fitted {res.residuals}")
    head = f"{'parameter':<12}{'unit':>8}{'initial':>12}{'estimate':>12}{'1-sigma':>11}"
    print(head + (f"{'truth':>12}{'error':>11}" if truth else ""))
    for k, v in res.values.items():
        if k.startswith("scale") and k not in res.fitted:
            continue
        s, unit = _SHOW[k]
        sig = res.sigma.get(k)
        line = (
            f"{k:<12}{unit:>8}{cell(initial.get(k, float('nan')) * s, 12)}{cell(v * s, 12)}"
            f"{cell(sig * s if sig is not None else float('nan'), 11)}"
        )
        if truth:
            line += f"{cell(truth[k] * s, 12)}{cell((v - truth[k]) * s, 11)}"
        print(line)
    print(
        f"train endpoint error: mean {res.train.mean_px:.3f} px, median "
        f"{res.train.median_px:.3f}, p95 {res.train.p95_px:.3f}"
    )
    if res.holdout.n:
        print(
            f"hold-out endpoint error: mean {res.holdout.mean_px:.3f} px, median "
            f"{res.holdout.median_px:.3f}, p95 {res.holdout.p95_px:.3f} ({res.holdout.n} "
            f"streaks)"
        )
    for w in res.warnings:
        print(f"warning: {w}")
