"""The natural-scene and axis-search parts of ``blurtrack calibrate`` (CLI layer of
:mod:`calib.natural.pipeline` and :mod:`calib.axes.search`; registered through :mod:`calib.cli`)."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: --fit default for natural scenes: the gyro scale is not observable from a few hundred
#: inter-frame rotations of hand shake (it trades with the focal lengths); it is fitted under
#: a prior instead (--gyro-scale-prior, :mod:`calib.natural.scale`).
NATURAL_FIT = "timeshift,fx,fy,cx,cy,readout,bias,rotation"


def add_natural_args(p: argparse.ArgumentParser) -> None:
    """``blurtrack calibrate`` options of natural-scene sessions."""
    p.add_argument(
        "--translation",
        # Spelled out, not imported from calib.natural.motion (that import costs CasADi at
        # parse time); a test checks the two lists agree.
        choices=("none", "auto", "per-pair", "travel"),
        default="auto",
        help="natural scenes: the camera's translation between frames. none: a far static "
        "scene (pure rotation); per-pair: an epipole per frame pair as a nuisance, every "
        "point's depth eliminated (near objects); travel: one direction of travel per "
        "second, carried to each frame and row by the gyro (driving); auto (default): "
        "travel when the rotation-only fit leaves more parallax than its missing "
        "coordinate explains",
    )
    p.add_argument(
        "--mask",
        action="append",
        default=[],
        metavar="X0,Y0,X1,Y1",
        help="natural scenes: leave out the tracks in this rectangle (px; repeatable), a part "
        "of the image that is not the static scene (a dashboard, a window's reflection)",
    )
    p.add_argument(
        "--gyro-scale-prior",
        # spelled out as --translation's (calib.natural.scale.SCALE_PRIORS; a test checks)
        choices=("map", "consider"),
        default="map",
        help="natural scenes with an unknown gyro scale (session.yaml gives none) and --fit "
        "without scale: map (default): its six entries fitted under a 0.3 %% Gaussian prior, "
        "sigma the posterior's; consider: left at the identity, its spread added to the sigma",
    )


def parse_mask(
    given: list[str], resolution: tuple[int, int]
) -> tuple[tuple[float, float, float, float], ...]:
    """``--mask X0,Y0,X1,Y1`` options as rectangles; one that is malformed, outside the
    ``(width, height)`` image or covering all of it is refused (:class:`CalibError`)."""
    from calib.errors import CalibError

    w, h = resolution
    out = []
    for text in given:
        try:
            x0, y0, x1, y1 = (float(v) for v in text.split(","))
        except ValueError:
            raise CalibError(f"--mask must be X0,Y0,X1,Y1 in px, got {text!r}") from None
        if not (x1 > x0 and y1 > y0 and x0 < w and y0 < h and x1 > 0 and y1 > 0):
            raise CalibError(f"--mask {text} is empty or outside the {w}x{h} image")
        if x0 <= 0 and y0 <= 0 and x1 >= w - 1 and y1 >= h - 1:
            raise CalibError(f"--mask {text} covers the whole {w}x{h} image")
        out.append((x0, y0, x1, y1))
    return tuple(out)


def is_natural(args: argparse.Namespace) -> bool:
    """Whether ``--target`` (or session.yaml's ``target.kind`` under ``auto``) says natural."""
    if args.target != "auto":
        return args.target == "natural"
    from blurtrack.io.session import load_session

    return load_session(args.session).meta.target_kind == "natural"


def print_axes(axes: Any) -> None:
    w = axes.winner
    print(
        f"axis search ({axes.source}, {axes.n_pairs} frame pairs, median rotation "
        f"{axes.motion_px:.2f} px): R_cam_imu {[list(map(int, r)) for r in w.R_cam_imu]}, "
        f"shift {w.timeshift_s * 1e3:+.1f} ms, score {w.score_px:.3f} px, runner-up "
        f"{axes.runner_up.score_px:.3f} px (margin {axes.margin:.1f})"
    )


def laser_axes(
    args: argparse.Namespace, streaks: Any, session: Any, initial: Any
) -> tuple[dict | None, Any]:
    """The axis search on a laser session's streak midpoints (``--axes search``).

    Returns the search as a dict (``None`` when skipped) and the initial calibration to fit
    from. Tables without midpoints skip the search with a warning.
    """
    if getattr(args, "translation", "auto") == "per-pair":
        from calib.errors import CalibError

        raise CalibError("--translation per-pair applies to natural-scene sessions")
    if args.axes != "search":
        return None, initial
    if streaks.mid is None:
        print(
            "warning: the streak table has no time midpoints: axis search skipped, "
            "session.yaml's T_cam_imu kept"
        )
        return None, initial
    from calib.axes.laser import search_axes_laser
    from calib.axes.search import check_axes
    from calib.data import relative_gyro
    from calib.tracks import mean_rows

    search = search_axes_laser(
        streaks.mid,
        mean_rows(streaks),
        streaks.frame,
        streaks.frame_t_s,
        streaks.exposure_s,
        initial.camera,
        relative_gyro(session.gyro(), streaks.t0_s),
        initial.timeshift_cam_imu_s,
        args.shift_window_ms * 1e-3,
    )
    check_axes(search)
    start = initial.with_(R_cam_imu=search.R_cam_imu, timeshift_cam_imu_s=search.winner.timeshift_s)
    print_axes(search)
    return search.to_dict(), start


def check_determined(res: Any, n_frames: int) -> None:
    """Refuse (:class:`CalibError`, exit 2, nothing written) a fit that leaves a fitted
    parameter undetermined (:func:`calib.uncertainty.undetermined`): its values would be a
    guess. The DeepGyro recording's 4 gyro-covered frame pairs gave sigma 3e6 s for the time
    offset and 6e8 px for fx, with status "ok"."""
    from calib.errors import CalibError
    from calib.uncertainty import undetermined

    if res.status == "failed":
        return
    bad = undetermined({k: res.sigma[k] for k in res.fitted if k in res.sigma})
    if bad:
        shown = ", ".join(f"{k} (sigma {res.sigma[k]:.3g})" for k in bad[:3])
        shown += f" and {len(bad) - 3} more" if len(bad) > 3 else ""
        raise CalibError(
            f"the recording does not determine {shown} from {n_frames} frames; no calibration "
            "written (record longer, with rotation about all three axes, or --fit fewer "
            "parameters)"
        )


def run_natural(
    args: argparse.Namespace,
    print_table: Callable[[Any, dict, dict | None], None],
) -> int:
    """``blurtrack calibrate`` on a natural-scene session (feature tracks, axis search)."""
    from blurtrack.features.tracks import TrackParams
    from blurtrack.io.session import load_session
    from calib.errors import CalibError
    from calib.fit import FitOptions
    from calib.natural.pipeline import calibrate_natural
    from calib.output import write_results, write_summary
    from calib.params import DEFAULT_FIT, theta_from
    from calib.result import named
    from calib.truth import truth_values

    if args.axes != "search":
        raise CalibError("natural-scene calibration always decides the axes (--axes search)")
    if args.centreline or args.frame_noise or args.streaks or args.from_truth:
        raise CalibError(
            "--centreline, --frame-noise, --streaks and --from-truth apply to laser sessions"
        )
    session = load_session(args.session)
    options = FitOptions(
        fit=NATURAL_FIT if args.fit == DEFAULT_FIT else args.fit,
        holdout_fraction=args.holdout,
        shift_window_s=args.shift_window_ms * 1e-3,
        residuals=args.residuals,
    )
    mask = parse_mask(args.mask, session.meta.camera.resolution)
    nat = calibrate_natural(
        session,
        options,
        params=TrackParams(exclude_px=mask),
        translation=args.translation,
        scale_prior=args.gyro_scale_prior,
    )
    res = nat.result
    summary = res.to_dict()
    summary.update(nat.summary())
    summary["target"] = "natural"
    summary["features"]["mask_px"] = [list(r) for r in mask]
    summary["options"] = dataclasses.asdict(options)
    summary["initial"] = named(theta_from(res.initial))
    truth = truth_values(session, res.initial)
    if truth is not None:
        summary["truth"] = truth
        summary["error_vs_truth"] = {k: res.values[k] - truth[k] for k in res.values}
    f = summary["features"]
    print(
        f"feature tracks: {f['tracked']} tracked in {f['frames'] - 1} frame pairs, "
        f"{f['tracks']} used by the fit (median {f['per_pair_median']:.0f} per pair, "
        f"{f['displacement_px_median']:.1f} px motion)"
    )
    print_axes(nat.axes)  # what the images decided, shown also when the fit is refused
    tr = nat.translation or {}
    if "ratio" in tr:
        print(
            f"translation: {tr['mode']} (chosen by {tr['chosen_by']}; rotation-only / "
            f"epipolar mean squared track error {tr['ratio']:.2f}, auto above {tr['auto_ratio']})"
        )
    out = Path(args.out)
    try:
        check_determined(res, nat.tracks.n_frames)
    except CalibError as exc:
        partial = write_partial(nat.axes, res.initial, out, str(exc), args.force)
        raise CalibError(f"{exc}; {partial}") from None
    # a failed fit never replaces the summary of the calibration it leaves in place
    details = write_summary(res, summary, out)
    print("(the endpoint errors below are feature-track errors)")
    print_table(res, summary["initial"], truth)
    try:
        print(write_results(res, out, details))
        return 0
    except CalibError as exc:
        partial = write_partial(nat.axes, res.initial, out, str(exc), args.force)
        raise CalibError(f"{exc}; {partial}") from None


#: What a partial calibration file holds (its ``partial.decided``).
PARTIAL_DECIDED = "camera-IMU axes and a coarse time offset (axis search)"


def partial_path(out: Path) -> Path:
    """Where ``calibrate --out OUT`` puts the decided axes when the fit is refused."""
    return out.with_name(out.stem + ".partial.yaml")


def write_partial(axes: Any, initial: Any, out: Path, reason: str, force: bool) -> str:
    """Write the axes the images decided (``axes``, an :class:`calib.axes.search.AxisSearch`) over
    ``initial`` (the session's own guesses for the rest) as a calibration file marked
    ``partial`` beside ``out``; returns the sentence for the refusal. An existing file is
    replaced only with ``force``."""
    from blurtrack.io.calibration import write_calibration

    path = partial_path(out)
    if path.exists() and not force:
        return f"the decided axes were not written: {path} exists (--force replaces it)"
    calib = initial.with_(
        R_cam_imu=axes.R_cam_imu,
        timeshift_cam_imu_s=axes.winner.timeshift_s,
        sigma={},
        partial={
            "decided": PARTIAL_DECIDED,
            "reason": reason,
            "axis_margin": f"{axes.margin:.2f}",
            "not_fitted": "intrinsics, readout, bias, fine time offset: the session's guesses",
        },
    )
    write_calibration(calib, path)
    return (
        f"the decided axes (margin {axes.margin:.1f}) are in {path}, marked partial: "
        "predict takes it, labelled"
    )
