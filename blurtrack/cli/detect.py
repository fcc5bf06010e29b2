"""``blurtrack detect SESSION [--out FILE]``: the streak table of every frame; ``blurtrack
detect PHOTO ... --out FILE``: that of still photographs (:mod:`blurtrack.cli.photos`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from blurtrack.cli.progress import Progress, add_quiet_arg
from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.guard import add_force_arg, check_output


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "detect",
        help="detect laser-dot streaks and write the streak table (Parquet)",
        description="Find every laser-dot streak in every frame of a session: sub-pixel "
        "start and end, centre line, brightness profile, quality flags; start/end resolved "
        "with the gyro (initial guesses), continuity and brightness. Given photographs "
        "(.jpg, .png, .tif) instead, each is one frame detected from its image alone: "
        "point light or extended source and quality_ok per detection, no start/end.",
    )
    p.add_argument(
        "session",
        type=Path,
        nargs="+",
        metavar="SESSION | PHOTO",
        help="session folder, or one or more photographs (then --out is needed)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output table (Parquet; default: SESSION/streaks.parquet, where calibrate and "
        "report look for it; photographs: required); a summary is written beside it as "
        "<stem>.summary.json",
    )
    p.add_argument(
        "--gyro",
        choices=("auto", "on", "off"),
        default="auto",
        help="use the gyro to tell start from end: auto (where it covers the "
        "frame), on (required), off (image only)",
    )
    p.add_argument("--params", type=Path, default=None, help="detection parameters (YAML)")
    p.add_argument(
        "--frames", default=None, metavar="A:B", help="only frames A..B-1 (Python slice syntax)"
    )
    p.add_argument(
        "--overlay",
        type=Path,
        default=None,
        metavar="PNG",
        help="also draw the detected streaks over the first frame with streaks (photographs: "
        "each detection coloured by its source; several photographs: a folder, one "
        "<stem>.png each)",
    )
    add_quiet_arg(p)
    add_force_arg(p)
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="processes that decode and detect frames (or photographs) in parallel (default: "
        "the CPU cores; the table does not depend on it)",
    )
    p.set_defaults(func=run)


def _frame_range(text: str | None, n: int) -> range | None:
    from blurtrack.errors import DetectionError

    if text is None:
        return None
    a, colon, b = text.partition(":")
    try:
        if not colon:
            raise ValueError
        chosen = range(n)[slice(int(a) if a else None, int(b) if b else None)]
    except ValueError:
        raise DetectionError(f"--frames must look like A:B, got {text!r}") from None
    if len(chosen) == 0:
        raise DetectionError(f"--frames {text} selects none of the session's {n} frames")
    return chosen


def detect_summary_path(table: Path, session_dir: Path) -> Path:
    """Where the detection summary goes: beside the table, or ``SESSION/derived/`` when the
    table is the session's own ``streaks.parquet`` (no other names are written into a session).
    """
    if table.name == "streaks.parquet" and table.parent.resolve() == session_dir.resolve():
        return session_dir / "derived" / "streaks.summary.json"
    return table.with_name(table.stem + ".summary.json")


def detect_to_table(
    session: Any,
    out: Path,
    params: Any = None,
    gyro: str = "auto",
    frames: range | None = None,
    quiet: bool = False,
    workers: int | None = None,
) -> Any:
    """Detect the streaks of ``session`` (with a progress bar) and write the table to ``out``.

    ``workers`` processes detect frames in parallel (default: the CPU cores; the table does not
    depend on it). Returns the :class:`blurtrack.detect.session.pipeline.DetectionResult`; shared by
    ``detect`` and by ``calibrate``/``report`` when a session has no table yet.
    """
    import cv2

    from blurtrack.detect.session.pipeline import default_workers, detect_session
    from blurtrack.detect.session.table import write_table

    cv2.setNumThreads(1)

    def meanwhile() -> None:
        import pyarrow.parquet  # noqa: F401  # the writer's import, while the workers detect

    total = len(frames) if frames is not None else len(session.frames)
    with Progress("detect", "frame", quiet) as bar:
        done = [0]

        def on_frame(_i: int, _fs: Any) -> None:
            done[0] += 1
            bar(done[0], total)

        result = detect_session(
            session,
            params,
            gyro=gyro,
            frames=frames,
            on_frame=on_frame,
            workers=default_workers() if workers is None else workers,
            meanwhile=meanwhile,
        )
    write_table(result.table, out)
    return result


def run(args: argparse.Namespace) -> int:
    from blurtrack.cli.photos import run_photos
    from blurtrack.detect.photos import is_photo
    from blurtrack.errors import DetectionError

    paths: list[Path] = args.session
    photos = [is_photo(p) for p in paths]
    if any(photos):
        if not all(photos):
            other = paths[photos.index(False)]
            raise DetectionError(
                f"detect takes one session folder or photographs, not both: {str(other)!r} "
                "is not a photograph (.jpg, .jpeg, .png, .tif, .tiff)"
            )
        return run_photos(args, paths)
    if len(paths) > 1:
        raise DetectionError(
            f"detect takes one session folder (got {len(paths)} paths); several photographs "
            "are named by their files (.jpg, .jpeg, .png, .tif, .tiff)"
        )
    args.session = paths[0]
    return _run_session(args)


def _run_session(args: argparse.Namespace) -> int:
    from blurtrack.detect import DetectParams
    from blurtrack.detect.overlay import write_streak_picture
    from blurtrack.io.session import load_session

    if args.out is None:
        args.out = Path(args.session) / "streaks.parquet"
    summary_path = detect_summary_path(args.out, Path(args.session))
    check_output(args.out, force=args.force, inputs=[args.params], siblings=[summary_path.name])
    # where the summary goes into SESSION/derived/: a real folder of the session, not a link
    check_output(summary_path, force=True, inputs=[args.params], what="the detection summary")
    if args.overlay is not None:
        check_output(args.overlay, force=args.force, what="--overlay")
    session = load_session(args.session)
    params = DetectParams.from_yaml(args.params) if args.params else DetectParams()
    frames = _frame_range(args.frames, len(session.frames))
    result = detect_to_table(session, args.out, params, args.gyro, frames, args.quiet, args.workers)
    summary = dict(result.summary, session=str(args.session), table=str(args.out))
    if args.overlay is not None:
        first = int(result.table["frame"].iloc[0])
        rows = result.table[result.table["frame"] == first]
        write_streak_picture(args.overlay, session.read_image(first), rows, first)
        summary["overlay"] = str(args.overlay)
    write_json_atomic(summary_path, summary)
    s = result.summary
    print(f"detect: {s['streaks']} streaks in {s['frames']} frames -> {args.out}")
    print(
        f"  orientation: {s['orientation_sources']}, median confidence "
        f"{s['orientation_confidence_median']:.3f}"
    )
    print(f"  flags: {s['flags']}")
    if s["gyro_timeshift_status"] == "found":
        by = {"refined": "templates", "session calibration": "session calibration"}
        how = (
            f"{by[s['gyro_timeshift_refinement']]}, scan {1e3 * s['gyro_timeshift_scan_s']:+.2f} "
            f"ms; readout {1e3 * s['gyro_readout_s']:.2f} ms"
            if s["gyro_timeshift_refinement"] in by
            else "coarse scan"
        )
        print(f"  camera-IMU time shift: {1e3 * s['gyro_timeshift_s']:+.2f} ms ({how})")
    elif s["gyro_timeshift_status"] != "no gyro":
        print(f"  camera-IMU time shift: {s['gyro_timeshift_status']}")
    order = s.get("gyro_readout_order") or {}
    if order.get("status") in ("top_first", "bottom_first", "undetermined"):
        words = {"top_first": "top first", "bottom_first": "bottom first"}
        llr = order.get("llr_top_first")
        odds = "" if llr is None else f" (log-likelihood ratio {llr:+.0f} for the top first)"
        print(f"  rows read: {words.get(order['status'], 'undetermined')}{odds}")
    sc = s["gyro_session_calibration"]
    if sc is not None and sc["status"] == "fitted":
        print(
            f"  session calibration: gyro-predicted vectors {sc['residual_before_px']:.2f} -> "
            f"{sc['residual_after_px']:.2f} px off the image's at the median "
            f"({sc['voters']} quality_ok streaks)"
        )
    lowered = s.get("gyro_trust_lowered_frames") or []
    if lowered:
        src = s["params"]["source"]
        print(
            f"  gyro check: the prediction misses {len(lowered)} of {s['gyro_trust_frames']} "
            f"checked frames by more than {src['end_gate_px'] - src['gyro_vector_tol_px']:.2f} "
            f"px (up to {s['gyro_trust_model_error_px']['max']:.2f} px); their tolerances "
            f"lowered: frames {lowered[:10]}{' ...' if len(lowered) > 10 else ''}"
        )
    light = s.get("light_colour") or {}
    if light.get("frames"):
        b, g, r = light["bgr"]
        print(
            f"  colour: {len(light['frames'])} of {s['frames']} frames measured on the luma of "
            f"their one-colour light (B, G, R = {b:.2f}, {g:.2f}, {r:.2f})"
        )
    tp, comps = s["gyro_template_frames"], s["gyro_template_components"]
    if tp.get("refined"):
        print(
            f"  template pass: {tp['refined']} of {sum(tp.values())} frames refined; "
            f"{comps['replaced']} of {comps['candidates']} candidate components re-measured "
            f"({comps['streaks']} streaks)"
        )
    if s["frames_without_streaks"]:
        print(
            f"  warning: {len(s['frames_without_streaks'])} frame(s) without streaks: "
            f"{s['frames_without_streaks'][:10]}",
            file=sys.stderr,
        )
    if s["frames_overexposed"]:
        print(
            f"  warning: {len(s['frames_overexposed'])} over-exposed frame(s) (mostly "
            f"saturated): {s['frames_overexposed'][:10]}",
            file=sys.stderr,
        )
    if (s.get("gyro_readout_order") or {}).get("status") == "bottom_first":
        print(f"  warning: {s['gyro_readout_order']['message']}", file=sys.stderr)
    if (s.get("gyro_direction") or {}).get("status") in ("contradicted", "unconfirmed"):
        print(f"  warning: {s['gyro_direction']['message']}", file=sys.stderr)
    motion = s.get("gyro_motion") or {}
    if motion.get("status") == "contradicted":
        print(
            f"  warning: {motion['message']}; the gyro is not used and no streak is "
            "quality_ok (--gyro off: the images' own verdict)",
            file=sys.stderr,
        )
    if s["frames_without_gyro"]:
        print(
            f"  warning: gyro does not cover {len(s['frames_without_gyro'])} frame(s); "
            "their orientation and quality_ok are image-only",
            file=sys.stderr,
        )
    # quality_ok is the images' alone where no frame was checked against the gyro: no gyro
    # (--gyro off, no IMU data), or one set aside (its direction contradicted or unconfirmed)
    if not s["gyro_trust_frames"] and motion.get("status") != "contradicted":
        from blurtrack.cli.photos import IMAGE_ONLY_NOTE

        print(f"  note: {IMAGE_ONLY_NOTE}")
    return 0
