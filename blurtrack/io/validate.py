"""Deep validation of a session: decodes every image, checks gyro gaps and coverage."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blurtrack.errors import BlurTrackError
from blurtrack.io.session import Session, load_session


@dataclass(frozen=True)
class ValidationReport:
    """What :func:`validate_session` found: hard errors and warnings, one line each."""

    session: Session
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    frames_covered: int = 0

    @property
    def ok(self) -> bool:
        return not self.errors


def validate_session(folder: str | Path, max_gyro_gap_s: float | None = None) -> ValidationReport:
    """Load a session, decode all its images and check that the gyro covers every exposure.

    Structural problems raise :class:`~blurtrack.errors.SessionError` (from loading); problems
    of individual frames are collected so that one bad frame does not hide the others.
    """
    s = load_session(folder)
    errors: list[str] = []
    warnings: list[str] = []
    for i in range(len(s.frames)):
        try:
            s.read_image(i)
        except BlurTrackError as exc:
            errors.append(str(exc))
    if s.imu_t_ns.size < 2:
        errors.append("the session has fewer than 2 gyro samples")
        return ValidationReport(s, errors, warnings, 0)
    trace = s.gyro(max_gyro_gap_s)
    shift = s.meta.imu.timeshift_cam_imu
    readout = s.meta.camera.readout_s
    covered = 0
    for i, (t, e) in enumerate(zip(s.frame_times_s, s.exposures_s, strict=True)):
        try:
            trace.check_coverage(t + shift, t + readout + e + shift)
            covered += 1
        except BlurTrackError as exc:
            warnings.append(f"frame {i}: {exc}")
    if covered == 0:
        errors.append("the gyro covers none of the frames' exposures")
    dt = np.diff(s.imu_times_s)
    if dt.size and dt.max() > 5 * np.median(dt):
        k = int(np.argmax(dt))
        warnings.append(
            f"longest gyro gap {1e3 * dt[k]:.1f} ms after sample {k} "
            f"(median interval {1e3 * np.median(dt):.2f} ms)"
        )
    return ValidationReport(s, errors, warnings, covered)
