"""``blurtrack record`` and ``blurtrack recover``: the rig's command line (listed in
``blurtrack.cli.COMMAND_MODULES`` as ``rigs.cli``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
from pathlib import Path
from typing import Any

from blurtrack.io.atomic import atomic_dir, write_json_atomic


def _floats4(text: str) -> tuple[float, float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("expected fx,fy,cx,cy") from None
    if len(values) != 4:
        raise argparse.ArgumentTypeError("expected four numbers fx,fy,cx,cy")
    return values  # type: ignore[return-value]


def _add_session_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("session initial guesses")
    g.add_argument(
        "--intrinsics",
        type=_floats4,
        default=None,
        metavar="FX,FY,CX,CY",
        help="camera intrinsics guess (default: fx = fy = width, image centre)",
    )
    g.add_argument(
        "--readout-s", type=float, default=None, help="rolling-shutter readout guess (s; default 0)"
    )
    g.add_argument(
        "--exposure-ms",
        type=float,
        default=None,
        help="exposure to assume where the camera does not report one",
    )
    g.add_argument("--target", choices=("laser-grid", "natural"), default="laser-grid")
    g.add_argument(
        "--turn-180",
        action="store_true",
        help="the camera reads its bottom row first (mounted upside down; blurtrack detect "
        "says so): write the session's frames turned by 180 degrees, the principal point and "
        "camera axes with them (the log keeps the frames as recorded)",
    )


def register(subparsers: Any) -> None:
    rec = subparsers.add_parser(
        "record",
        help="record an IMU and a camera into a crash-safe log and a session folder",
        description="Record IMU samples and camera frames with timestamps. Device URLs: "
        "serial:///dev/ttyUSB0?baud=921600&protocol=binary|ascii, loop://, "
        "sim://imu?rate=1000&flip=0.01...; v4l2://0, opencv://0, "
        "file:///path/video.mp4, sim://camera?fps=30&width=1280&height=720. "
        "Ctrl-C stops cleanly.",
    )
    rec.add_argument("--imu", metavar="URL", help="IMU device URL")
    rec.add_argument("--camera", metavar="URL", help="camera device URL")
    rec.add_argument("--out", required=True, type=Path, help="session folder to create")
    rec.add_argument(
        "--log",
        type=Path,
        default=None,
        help="recorder log (MCAP); default: OUT.mcap next to the session folder",
    )
    rec.add_argument("--duration", type=float, default=None, help="stop after this many s")
    rec.add_argument(
        "--flush-interval",
        type=float,
        default=0.25,
        help="seconds between log chunk flushes (the most a crash can lose)",
    )
    rec.add_argument("--no-convert", action="store_true", help="write the log only")
    _add_session_options(rec)
    rec.set_defaults(func=run_record)

    recov = subparsers.add_parser(
        "recover",
        help="salvage a recorder log cut short (crash, SIGKILL, full disk)",
        description="Copy every intact message of LOG into a finished log and, with "
        "--session, convert it to a session folder.",
    )
    recov.add_argument("log", type=Path, metavar="LOG")
    recov.add_argument(
        "--out",
        type=Path,
        default=None,
        help="repaired log (default: LOG with suffix .recovered.mcap)",
    )
    recov.add_argument("--session", type=Path, default=None, help="also write this session")
    _add_session_options(recov)
    recov.set_defaults(func=run_recover)


def _options(args: argparse.Namespace) -> Any:  # rigs.convert.ConvertOptions (lazy import)
    from rigs.convert import ConvertOptions
    from rigs.errors import RigError

    if args.exposure_ms is not None and not args.exposure_ms > 0:
        raise RigError("--exposure-ms must be positive")
    exposure_ns = None if args.exposure_ms is None else round(args.exposure_ms * 1e6)
    return ConvertOptions(
        intrinsics=args.intrinsics,
        readout_s=args.readout_s,
        target_kind=args.target,
        exposure_ns=exposure_ns,
    )


def _log_to_session(log: Path, folder: Path, options: Any, turn: bool) -> Any:
    """:func:`rigs.convert.log_to_session` into ``folder`` (the command's unpublished output),
    its frames then turned by 180 degrees where ``turn`` (:mod:`blurtrack.io.turn`)."""
    from rigs.convert import log_to_session

    conv = log_to_session(log, folder, options)
    if not turn:
        return conv
    from blurtrack.io.turn import turn_session_files

    turned = turn_session_files(folder)
    return dataclasses.replace(conv, notes=[*conv.notes, f"{turned} frames turned by 180 degrees"])


def _check_new_folder(folder: Path) -> None:
    from blurtrack.io.guard import check_new_folder

    check_new_folder(folder, "session folder")


def _write_summary(folder: Path, summary: dict[str, Any]) -> None:
    write_json_atomic(folder / "summary.json", summary, default=str)


def run_record(args: argparse.Namespace) -> int:
    from blurtrack.io.guard import check_output
    from rigs.camera import open_camera
    from rigs.errors import RigError
    from rigs.imu import open_imu
    from rigs.recorder import Recorder, RecorderConfig, RecorderStatus
    from rigs.sim.shared_rig import rig_guess_for_urls

    if not args.imu and not args.camera:
        raise RigError("give --imu URL, --camera URL or both")
    if not args.camera and not args.no_convert:  # refuse now, not after the whole duration
        raise RigError("a session needs camera frames: give --camera URL (or --no-convert)")
    if not args.imu and not args.no_convert:
        raise RigError("a session needs gyro samples: give --imu URL (or --no-convert)")
    out: Path = args.out
    log_path: Path = args.log or out.with_name(out.name + ".mcap")
    options = _options(args)
    if not args.no_convert:
        _check_new_folder(out)
    if log_path.exists():
        raise RigError(f"log {log_path} already exists; choose another --log")
    check_output(log_path, what="--log")
    try:
        config = RecorderConfig(flush_interval_s=args.flush_interval, duration_s=args.duration)
    except ValueError as exc:
        raise RigError(str(exc)) from None
    imu = open_imu(args.imu) if args.imu else None
    try:
        camera = open_camera(args.camera) if args.camera else None
    except BaseException:
        if imu is not None:
            imu.close()
        raise
    tty = sys.stdout.isatty()

    def show(status: RecorderStatus) -> None:
        if tty:
            print("\r" + status.line(), end="", flush=True)
        else:
            print(status.line(), flush=True)

    metadata = {
        "imu_url": args.imu or "",
        "camera_url": args.camera or "",
        "imu_min_latency_s": repr(imu.min_latency_s if imu is not None else 0.0),
    }
    guess = rig_guess_for_urls(args.imu, args.camera)
    if guess is not None:
        metadata["rig_guess"] = json.dumps(guess)
    recorder = Recorder(log_path, imu, camera, metadata, config, on_status=show)

    def on_signal(signum: int, _frame: Any) -> None:
        # first Ctrl-C or SIGTERM: stop cleanly (never interrupt a half-written record);
        # a second Ctrl-C interrupts for real
        recorder.stop()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        result = recorder.run()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if tty:
            print()
        for dev in (imu, camera):
            if dev is not None:
                dev.close()
    s = result.status
    print(
        f"recorded {s.imu_samples} IMU samples and {s.frames} frames in {s.elapsed_s:.1f} s "
        f"into {log_path} (stopped by {result.stopped_by})"
    )
    for warning in result.warnings:
        print(f"  warning: {warning}")
    if result.imu_stats:
        st = result.imu_stats
        print(
            f"IMU link: {st['received']} samples received = {st['kept']} kept + "
            f"{st['duplicates']} duplicates + {st['bad_counter']} bad counters + "
            f"{st['time_jumps_back']} time jumps back; {st['crc_errors']} CRC errors, "
            f"{st['dropped']} samples dropped in {st['gaps']} gaps, {st['resyncs']} resyncs "
            f"({st['skipped_bytes']} bytes skipped), {st['counter_wraps']} counter wraps, "
            f"{st['time_wraps']} clock wraps"
        )
    if imu is not None and s.imu_samples == 0 and result.error is None:
        raise RigError(
            f"the IMU {args.imu} delivered no samples in {s.elapsed_s:.1f} s; "
            f"no session written (the log {log_path} is kept)"
        )
    summary: dict[str, Any] = {"command": "record", "recording": result.as_dict()}
    if not args.no_convert:
        try:
            with atomic_dir(out) as tmp:  # a full disk leaves no half session behind
                conv = dataclasses.replace(
                    _log_to_session(log_path, tmp, options, args.turn_180), folder=out
                )
        except RigError as exc:
            if result.error is None:
                raise
            raise RigError(
                f"recording ended early: {result.error}; no session written "
                f"({exc}); the log {log_path} keeps what was recorded"
            ) from None
        summary["session"] = conv.as_dict()
        _write_summary(out, summary)
        print(
            f"session {out}: {conv.frames} frames, {conv.imu_samples} IMU samples"
            + "".join(f"; {n}" for n in conv.notes)
        )
    if result.error is not None:
        where = (
            f"; the session in {out} holds everything recorded before"
            if not args.no_convert
            else f"; the log {log_path} holds everything before"
        )
        raise RigError(f"recording ended early: {result.error}{where}")
    return 0


def run_recover(args: argparse.Namespace) -> int:
    from blurtrack.io.guard import check_output
    from rigs.errors import RigError
    from rigs.recover import recover_log

    options = _options(args)
    log: Path = args.log
    out: Path = args.out or log.with_name(log.stem + ".recovered.mcap")
    if args.session is not None:
        _check_new_folder(args.session)
    check_output(out, inputs=[log], what="--out")
    res = recover_log(log, out)
    state = "was complete" if res.was_complete else f"was cut short: {res.damage}"
    print(f"{log} {state}; kept {res.imu_samples} IMU samples and {res.frames} frames in {out}")
    if args.session is not None and res.imu_samples == 0:  # as record refuses it
        raise RigError(
            f"{log} holds no IMU samples; no session written (the recovered log {out} is kept)"
        )
    if args.session is not None:
        with atomic_dir(args.session) as tmp:  # a full disk leaves no half session behind
            conv = dataclasses.replace(
                _log_to_session(out, tmp, options, args.turn_180), folder=args.session
            )
        _write_summary(
            args.session,
            {
                "command": "recover",
                "log": str(log),
                "recovered_log": str(out),
                "was_complete": res.was_complete,
                "damage": res.damage,
                "session": conv.as_dict(),
            },
        )
        print(f"session {args.session}: {conv.frames} frames, {conv.imu_samples} IMU samples")
    return 0
