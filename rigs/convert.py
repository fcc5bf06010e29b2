"""Conversion of a recorder log (complete or truncated) into a session folder (DESIGN).

IMU device time becomes host time through the lower-envelope clock map of :mod:`rigs.timesync`;
camera stamps are already on the host clock. Both streams therefore land on one timeline and
``session.yaml`` starts with ``timeshift_cam_imu: 0`` as the initial guess for calibration.
What the rig cannot know (intrinsics) is an explicit initial guess, marked as such in
``session.yaml`` under ``recording``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from blurtrack.errors import BlurTrackError
from blurtrack.geometry.camera import Camera
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter
from rigs.errors import RecorderLogError
from rigs.reclog import LogScan, iter_frames, scan_log
from rigs.recorder import rate_of
from rigs.timesync import fit_clock_map_windowed

#: Device time per clock-map window: long enough for a tight envelope, short enough to follow
#: a drift that changes with temperature.
CLOCK_WINDOW_S = 60.0


@dataclass(frozen=True)
class ConvertOptions:
    """Initial guesses written to ``session.yaml``; each one left None comes from the log's
    ``rig_guess`` metadata (what a simulated rig says about itself), else a default:
    intrinsics fx = fy = image width (about 53 degrees of horizontal field of view) and the
    image centre, readout 0, R_cam_imu identity (then ``axes_known: false``). ``exposure_ns``
    is used only for frames whose camera reported no exposure."""

    intrinsics: tuple[float, float, float, float] | None = None
    readout_s: float | None = None
    target_kind: str = "laser-grid"
    exposure_ns: int | None = None
    R_cam_imu: tuple[tuple[float, float, float], ...] | None = None

    def __post_init__(self) -> None:
        if self.exposure_ns is not None and self.exposure_ns <= 0:
            raise RecorderLogError("the fallback exposure must be positive")
        if self.R_cam_imu is not None:
            R = np.asarray(self.R_cam_imu, dtype=float)
            if (
                R.shape != (3, 3)
                or not np.allclose(R @ R.T, np.eye(3), atol=1e-6)
                or np.linalg.det(R) < 0
            ):
                raise RecorderLogError("R_cam_imu must be a 3x3 rotation matrix")


@dataclass
class ConvertResult:
    """What went into the session folder."""

    folder: Path
    frames: int
    imu_samples: int
    log_complete: bool
    damage: str
    clock_map: dict[str, Any] = field(default_factory=dict)
    skipped_frames: int = 0
    skipped_imu: int = 0
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "session": str(self.folder),
            "frames": self.frames,
            "imu_samples": self.imu_samples,
            "log_complete": self.log_complete,
            "damage": self.damage,
            "clock_map": self.clock_map,
            "skipped_frames": self.skipped_frames,
            "skipped_imu": self.skipped_imu,
            "notes": self.notes,
        }


def _imu_host_times(scan: LogScan, result: ConvertResult) -> tuple[np.ndarray, np.ndarray]:
    """Host-clock times (int64 ns) of the IMU samples kept, and the mask of kept samples."""
    n = scan.imu_index.size
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool)
    dev_ns = scan.imu_t_dev_us * 1000
    keep = np.ones(n, bool)
    keep[1:] = np.diff(scan.imu_t_dev_us) > 0  # rigs.sequence guarantees it for live logs
    if n < 2:
        raise RecorderLogError("the log holds a single IMU sample; cannot map device time")
    min_latency = float(scan.metadata.get("imu_min_latency_s", "0") or 0.0)
    cmap = fit_clock_map_windowed(dev_ns[keep], scan.imu_host_ns[keep], min_latency, CLOCK_WINDOW_S)
    result.clock_map = cmap.as_dict()
    result.skipped_imu = int(n - np.count_nonzero(keep))
    return cmap.to_host_ns(dev_ns[keep]), keep


def _rig_guess(metadata: dict[str, str]) -> dict[str, Any]:
    """The ``rig_guess`` metadata (JSON) of a log, checked; {} when absent."""
    text = metadata.get("rig_guess")
    if not text:
        return {}
    try:
        guess = json.loads(text)
        out: dict[str, Any] = {}
        if "intrinsics" in guess:
            out["intrinsics"] = tuple(float(v) for v in guess["intrinsics"])
            if len(out["intrinsics"]) != 4:
                raise ValueError("four intrinsics expected")
        if "readout_s" in guess:
            out["readout_s"] = float(guess["readout_s"])
        if "R_cam_imu" in guess:
            out["R_cam_imu"] = ConvertOptions(
                R_cam_imu=cast(
                    "tuple[tuple[float, float, float], ...]",
                    tuple(tuple(float(v) for v in row) for row in guess["R_cam_imu"]),
                )
            ).R_cam_imu
        return out
    except (ValueError, TypeError, KeyError) as exc:
        raise RecorderLogError(f"the log's rig_guess metadata is malformed ({exc})") from None


def log_to_session(
    log_path: str | Path, folder: str | Path, options: ConvertOptions | None = None
) -> ConvertResult:
    """Write the session folder ``folder`` (must not exist or be empty) from a recorder log."""
    options = options or ConvertOptions()
    log_path, folder = Path(log_path), Path(folder)
    scan = scan_log(log_path)
    result = ConvertResult(folder, 0, 0, scan.complete, scan.damage)
    if scan.frame_timestamps_ns.size == 0:
        raise RecorderLogError(
            f"{log_path} holds no camera frames; a session needs a camera "
            "(record IMU-only logs with --no-convert)"
        )
    unknown_exposure = bool(np.any(scan.frame_exposures_ns <= 0))
    if unknown_exposure and options.exposure_ns is None:
        raise RecorderLogError(
            "the camera reported no exposure time for some frames; "
            "give the exposure explicitly (--exposure-ms)"
        )
    if scan.imu_index.size == 0:
        raise RecorderLogError(
            f"{log_path} holds no IMU samples; a session needs the gyro "
            "(keep camera-only logs with --no-convert)"
        )
    imu_t_ns, keep = _imu_host_times(scan, result)
    image = next(iter_frames(log_path)).image()
    h, w = image.shape[:2]
    guess = _rig_guess(scan.metadata)
    intrinsics = options.intrinsics or guess.get("intrinsics")
    guessed = intrinsics is None
    if intrinsics is None:
        intrinsics = (float(w), float(w), (w - 1) / 2.0, (h - 1) / 2.0)
        result.notes.append("intrinsics are a guess (fx = fy = width); calibrate them")
    readout_s = (
        options.readout_s if options.readout_s is not None else float(guess.get("readout_s", 0.0))
    )
    T_cam_imu = np.eye(4)
    R = options.R_cam_imu if options.R_cam_imu is not None else guess.get("R_cam_imu")
    if R is not None:
        T_cam_imu[:3, :3] = np.asarray(R, dtype=float)
    else:
        result.notes.append("camera-IMU axes unknown (identity placeholder); calibrate decides")
    if unknown_exposure:
        result.notes.append(
            f"exposure not reported by the camera; {options.exposure_ns} ns assumed as given"
        )
    imu_rate = rate_of(scan.imu_t_dev_us * 1000) if keep.any() else 0.0
    recording: dict[str, Any] = {k: v for k, v in scan.metadata.items() if k != "format"}
    recording.update(
        {
            "log": log_path.name,
            "log_complete": scan.complete,
            "damage": scan.damage,
            "clock_map": result.clock_map,
            "imu_stats": scan.last_stats.get("imu", {}),
            "camera_dropped": scan.last_stats.get("camera_dropped", 0),
            "intrinsics_guessed": guessed,
        }
    )
    try:
        meta = SessionMeta(
            camera=Camera(resolution=(w, h), intrinsics=tuple(intrinsics), readout_s=readout_s),
            imu=ImuConfig(
                rate_hz=imu_rate if imu_rate > 0 else 200.0,
                T_cam_imu=T_cam_imu,
                axes_known=R is not None,
            ),
            target_kind=options.target_kind,
            extra={"recording": recording},
        )
        with SessionWriter(folder, meta) as writer:
            accel = scan.accel_mps2[keep] if scan.accel_mps2 is not None else None
            writer.add_imu(imu_t_ns, scan.gyro_radps[keep], accel)
            result.imu_samples = int(imu_t_ns.size)
            last_ts: int | None = None
            for rec in iter_frames(log_path):
                if last_ts is not None and rec.timestamp_ns <= last_ts:
                    result.skipped_frames += 1
                    continue
                img = rec.image()
                exposure = rec.exposure_ns if rec.exposure_ns > 0 else options.exposure_ns
                assert exposure is not None  # unknown exposures without --exposure-ms raised above
                writer.add_frame(rec.timestamp_ns, img, int(exposure))
                last_ts = rec.timestamp_ns
                result.frames += 1
    except RecorderLogError:
        raise
    except BlurTrackError as exc:
        raise RecorderLogError(f"cannot write session {folder}: {exc}") from None
    if result.skipped_frames:
        result.notes.append(f"{result.skipped_frames} frames with non-increasing stamps skipped")
    return result
