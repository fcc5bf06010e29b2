"""Does the gyro move the dots as far as the images show? (the first of the gyro's stages,
:func:`blurtrack.detect.gyro.gyrostages.gyro_stages`).

A camera turning by the small angle ``theta`` (rad) over an exposure moves a point near the
optical axis by ``f theta`` px (``f`` the focal length in px); a roll about the axis moves a
point at radius ``r`` by ``r theta``, less. So ``f |integral of omega dt|`` over a frame's
exposure bounds the length of its streaks' start-to-end vectors, and is their length for a
shake of pan and tilt. :func:`gyro_motion` takes the median of that bound over the frames
with streaks, over time shifts within the time-shift scan's reach of the session's initial
one, against the median start-to-end length of the frames' long streaks (longer than the
scan's ``timeshift.scan_min_length_px``, neither clipped nor merged, as the scan picks them;
measured start to end, as the gyro's bound is). They agree
within :data:`MOTION_RATIO` either way on every simulated session: the gyro's blur is
0.92-1.36 times the streaks' on ten sessions (`hard` 1, 2 and 4, `dense`, `realistic`,
`optics`, `phone`, `hard_long_dense_grid`, `dense_long_grid`, `hard_long_exposure`). A gyro
that reads zeros predicts no motion; one recorded in degrees/s where the session format asks
for radians/s 57 times too much (on a `dense` session, whose rates then stay under the load's
bound, the blur model's rolling-shutter iteration followed the points far off the frame and
its integration of the rotation ran out of memory); another device's gyro or the stream of
another session predicts unrelated lengths. The check cannot tell these from frames whose lines
are not the dots' blur: on the phone drive of ``../shared/data/real`` (a street scene, 5.1 ms
exposures, no laser dots) the gyro turns the camera by 0.36 px an exposure, rightly, while the
lamps and edges the detector finds there are 18.7 px long; its message names both sides.

The gyro is then not used, and since calibration needs it and the images alone cannot see a
dot's path turn back within the exposure, no streak is ``quality_ok``. No integration of the
blur model is needed: the rates are integrated on a fixed grid per exposure
(:data:`SAMPLES`), which is cheap whatever their size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.timeshift import SEARCH_S
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace

#: The gyro's motion and the images' agree within this factor either way (module text).
MOTION_RATIO = 5.0
#: Rate samples per exposure for the integrated rotation (the trapezoid rule).
SAMPLES = 33
#: Time shifts tried, spread over the time-shift scan's reach (+-50 ms) of the initial one.
SHIFTS = 9
#: Frames sampled (spread over the session).
MAX_FRAMES = 12


@dataclass(frozen=True)
class GyroMotion:
    """The gyro's motion against the images': ``gyro_px``, the median over frames and shifts
    of ``f |integral omega dt|`` over an exposure, and ``image_px``, the median length of the
    frames' long streaks (px); ``frames``: how many frames were measured."""

    gyro_px: float
    image_px: float
    frames: int

    @property
    def agrees(self) -> bool:
        """Whether the two agree within :data:`MOTION_RATIO` either way."""
        return bool(self.image_px / MOTION_RATIO <= self.gyro_px <= self.image_px * MOTION_RATIO)

    def message(self) -> str:
        """One line on a gyro whose motion the images contradict, with the causes on either
        side: the gyro's stream, or frames whose lines are not the dots' blur."""
        g, i = self.gyro_px, self.image_px
        gyro_side = (
            "a dead or disconnected gyro stream, rates far too small"
            if g < i
            else "rates in degrees/s where the session format asks for radians/s"
        )
        return (
            f"the gyro and the frames disagree on the motion: the gyro turns the camera by "
            f"{g:.2f} px over an exposure, the frames' streaks are {i:.1f} px long (medians of "
            f"{self.frames} frames): {gyro_side} or another device's gyro, or frames whose "
            "lines are not the dots' blur (a scene without laser dots)"
        )

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "gyro_px": self.gyro_px,
            "image_px": self.image_px,
            "frames": self.frames,
            "status": "agrees" if self.agrees else "contradicted",
        }
        if not self.agrees:
            out["message"] = self.message()
        return out


def _long_lengths(fs: FrameStreaks, min_length_px: float) -> np.ndarray:
    """The start-to-end lengths (px) of a frame's streaks longer than ``min_length_px``,
    neither clipped nor merged (the time-shift scan's choice, by chord not arc)."""
    chord = np.hypot(*(fs.end_b - fs.end_a).T)
    use = (chord > min_length_px) & ~fs.flags["clipped"] & ~fs.flags["merged"]
    return np.asarray(chord[use])


def gyro_motion(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    calib: Calibration,
    gyro: GyroTrace,
    params: DetectParams | None = None,
) -> GyroMotion | None:
    """The gyro's motion against the images' (module text) over up to :data:`MAX_FRAMES`
    frames with long streaks whose exposures the gyro covers at every shift tried; None where
    no frame has a long streak or the gyro covers none (nothing to compare)."""
    p = params or DetectParams()
    initial = float(calib.timeshift_cam_imu_s)
    f_px = float(np.mean(calib.camera.intrinsics[:2]))
    t_lo, t_hi = float(gyro.t_s[0]) + SEARCH_S, float(gyro.t_s[-1]) - SEARCH_S
    use = [
        k
        for k, (fs, tm) in enumerate(zip(frames, timings, strict=True))
        if len(fs)
        and t_lo <= tm.t_s + initial
        and tm.t_s + initial + tm.exposure_s <= t_hi
        and _long_lengths(fs, p.timeshift.scan_min_length_px).size
    ]
    if not use:
        return None
    spread = np.unique(np.linspace(0, len(use) - 1, min(MAX_FRAMES, len(use))).round())
    pick = [use[int(i)] for i in spread]
    shifts = initial + np.linspace(-SEARCH_S, SEARCH_S, SHIFTS)
    u = np.linspace(0.0, 1.0, SAMPLES)
    moved, seen = [], []
    for k in pick:
        tm = timings[k]
        # (SHIFTS, SAMPLES) IMU times over the exposure at each shift
        t = tm.t_s + shifts[:, None] + tm.exposure_s * u[None, :]
        w = gyro.omega_at(t.ravel()).reshape(SHIFTS, SAMPLES, 3)
        # The trapezoid rule over the samples: (SHIFTS, 3) rad
        angle = 0.5 * (w[:, 1:] + w[:, :-1]).sum(axis=1) * (tm.exposure_s / (SAMPLES - 1))
        moved.append(f_px * np.linalg.norm(angle, axis=1))
        seen.append(_long_lengths(frames[k], p.timeshift.scan_min_length_px))
    return GyroMotion(
        gyro_px=float(np.median(np.concatenate(moved))),
        image_px=float(np.median(np.concatenate(seen))),
        frames=len(pick),
    )
