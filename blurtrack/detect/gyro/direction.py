"""Does the gyro's motion run the way the images say? (the session's axes checked against its
own frames, before the gyro is used for anything but the orientation-free time-shift scan).

Start-to-end vectors cannot tell a motion from its reverse, so a camera-IMU rotation that is
wrong by a half turn about the optical axis (the x and y rates' signs swapped: a common
mix-up of a phone's sensor axes) fits the streaks as well as the right one, the time-shift
scan finds its shift, and the gyro's orientation cue then names the wrong end of every streak
the start, at full confidence. The images decide the direction by themselves: in the gap
between two exposures a dot goes on moving, so one end of a streak lies near an end of the
previous frame's streak of the same dot and the other near the next frame's
(:func:`~blurtrack.detect.session.orientation.continuity_cues`, here without any tentative
orientation: any end of a neighbouring frame may continue a streak).

Where both cues are decisive (``|LLR| >= orientation.direction_llr``) they agree on 87-100 %
of the streaks of ``dense``/``hard`` sessions (97 % median over frames; the worst `hard`
frame 47 %: dense grids put other dots' ends near an extrapolated one). A half-turn error
leaves 0.4 %; a half turn about the x axis (pan and roll reversed, tilt not) leaves frames at
0 % beside frames at 100 %. So the gyro is *contradicted* where a sampled frame agrees on
less than ``orientation.direction_frame_agree`` of at least :data:`MIN_PAIRS` decisive
streaks, or the sample as a whole on less than ``orientation.direction_session_agree`` by
more than chance explains (:data:`DECIDE_SIGMAS`); detection then goes on from the images
alone and says why (``--gyro on`` refuses). A sample that agrees at chance says nothing
about the axes: continuity read on fragments of crossing streaks, or on ends beside other
dots' ends, agrees about half the time whichever way the gyro runs (``hard_long_dense_grid``
103, a session whose axes are right: 113 of 230, which a plain 50 % cut called a reversal,
leaving 76 ``quality_ok`` hairpin arms from the images alone, all wrong). So it
does where the session says its axes are a guess (``imu.axes_known: false``, as the importers
write for phones whose sensor axes are not published) and the images cannot confirm the
direction either way (*unconfirmed*).

Continuity's premise, that a dot goes on the way it went, fails where the shake turns back in
the gap between two exposures or within the exposure (the streak's visible end is then a turn,
not where the dot was at the exposure's start or end): there the images name the wrong end, as
a wrong axis would (``phone`` seed 6, frame 5, the last, with one neighbour: 9 of 54 decisive
starts right by continuity, 200 of 200 by the gyro). Whether the motion turns does not depend
on the axes: the image velocities at two times are mapped alike by an error of the axes' signs
or order (a rotation or reflection of the rates keeps the angle between them, exactly at the
image centre and to first order elsewhere), so the gyro tells it whichever way its axes are.
The streaks whose predicted motion turns back (two of its velocities at an obtuse angle, any
two: a gradual turn back rotates the velocity a little from sample to sample) within their
exposure (:data:`TURN_SAMPLES` samples) or from the last to the first
:data:`GAP_TANGENT_FRACTION` of the exposures about a gap that continuity reads are left out
of the check.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.paramsections import OrientationParams
from blurtrack.detect.session.orientation import (
    CueErrors,
    FrameTiming,
    continuity_cues,
    gyro_cues_batch,
)
from blurtrack.errors import CoverageError

#: Frames sampled for the check (spread over the session): ~3600 streaks on `dense`, 0.1 s.
#: A partial reversal (a half turn about the x axis) shows on some frames only: where a fifth
#: of the frames are reversed, 12 samples include one with a probability of 1 - 0.8^12 = 93 %.
SAMPLE_FRAMES = 12
#: Fewest decisive streaks for a frame's (and, twice that, the sample's) agreement to count:
#: at 30 pairs a frame agreeing on 50 % falls under 20 % with a probability of ~1e-4.
MIN_PAIRS = 30
#: The stretch of each exposure next to a gap (a fraction of the exposure) over which a dot's
#: predicted motion into and out of the gap is taken: the streak's end that continuity
#: extrapolates (its tangent over the last few px).
GAP_TANGENT_FRACTION = 0.25
#: Samples of a dot's predicted path over its exposure for the turn test: 8 steps of 1/8 of the
#: exposure (a turn and back within one step is missed: the shake's dominant 5-15 Hz turn twice
#: in 30-100 ms, over 2.5 ms steps at the simulator's 20 ms exposures).
TURN_SAMPLES = 9
#: The sample's agreement contradicts the gyro only where it lies this many binomial standard
#: errors (at ``orientation.direction_session_agree`` ``a``: ``sqrt(a (1 - a) / n)`` for ``n``
#: decisive pairs) below ``a``. At 50 % the cut is ``50 % - 150 % / sqrt(n)``: 30.6 % at the
#: 60 pairs the check needs, 40.1 % at 230. A sample at chance falls below it with a
#: probability of 0.13 %; a reversed axis set (0.4 % agreement) does from 10 pairs on.
DECIDE_SIGMAS = 3.0


@dataclass(frozen=True)
class GyroDirection:
    """The check's outcome: ``status`` ``consistent``, ``contradicted`` or ``undetermined``
    (too few decisive pairs: a gyro that reads zero, frames too far apart for continuity),
    ``unconfirmed`` where that happens to a session whose axes are a guess;
    decisive pairs and those agreeing over the sampled frames; the sampled frames' positions
    in the session's frame list that disagree (``frames_contradicted``)."""

    status: str
    decisive: int = 0
    agree: int = 0
    frames_sampled: int = 0
    frames_contradicted: list[int] = field(default_factory=list)

    def as_dict(self, frame_index: list[int]) -> dict[str, Any]:
        """For the summary: frame numbers (``frame_index``) instead of positions, and the
        user's line where the gyro was contradicted."""
        out: dict[str, Any] = {
            "status": self.status,
            "decisive": self.decisive,
            "agree": self.agree,
            "frames_sampled": self.frames_sampled,
            "frames_contradicted": [frame_index[k] for k in self.frames_contradicted],
        }
        if not self.usable:
            out["message"] = self.message(frame_index)
        return out

    @property
    def usable(self) -> bool:
        """May the gyro be used beyond the time-shift scan?"""
        return self.status not in ("contradicted", "unconfirmed")

    def message(self, frame_index: list[int], refused: bool = False) -> str:
        """One line for the user (``frame_index``: the session's frame numbers; ``refused``:
        for ``--gyro on``, which stops instead of going on without the gyro)."""
        then = "--gyro on stops" if refused else "detection used the images alone"
        if self.status == "unconfirmed":
            return (
                "the session's camera-IMU axes are a guess (imu.axes_known: false) and the "
                f"images confirm no direction of the gyro's motion ({self.agree} of "
                f"{self.decisive} decisive streaks agree); {then} (blurtrack calibrate "
                "searches the axes)"
            )
        bad = [frame_index[k] for k in self.frames_contradicted]
        where = f" (frames {bad})" if bad else ""
        return (
            f"the gyro's predicted motion runs against the images on {self.decisive - self.agree}"
            f" of {self.decisive} decisive streaks{where}: R_cam_imu (or the gyro's axis signs) "
            f"is wrong; {then} (blurtrack calibrate searches the axes)"
        )


def sampled_frames(covered: list[int], count: int = SAMPLE_FRAMES) -> list[int]:
    """Up to ``count`` of ``covered`` spread evenly (first and last included)."""
    if len(covered) <= count:
        return list(covered)
    at = np.unique(np.round(np.linspace(0, len(covered) - 1, count)).astype(int))
    return [covered[i] for i in at.tolist()]


def gyro_direction(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    errors: CueErrors,
    params: OrientationParams,
    axes_known: bool = True,
) -> GyroDirection:
    """Check the gyro's direction of motion against the frames' continuity (module text).

    ``found``/``timings``: the session's first-pass frames; ``covered``: the positions the gyro
    covers; ``model``: the blur model the cues would use; ``errors``: their error model;
    ``axes_known``: the session's ``imu.axes_known`` (false: the axes are a guess, and a
    direction the images cannot confirm is ``unconfirmed`` rather than ``undetermined``).
    """
    # Too few decisive pairs: no evidence either way, which a guessed axis set cannot pass.
    undetermined = "undetermined" if axes_known else "unconfirmed"
    sample = [k for k in sampled_frames(covered) if len(found[k])]
    if not sample:
        return GyroDirection(undetermined)
    try:
        gyro = gyro_cues_batch(
            [found[k] for k in sample], [timings[k] for k in sample], model, errors
        )
    except CoverageError:
        return GyroDirection(undetermined, frames_sampled=len(sample))
    lo = params.direction_llr
    decisive = agree = 0
    bad: list[int] = []
    for k, g in zip(sample, gyro, strict=True):
        # The frame and its neighbours only: continuity reads nothing further.
        around = [j for j in (k - 1, k, k + 1) if 0 <= j < len(found)]
        cont = continuity_cues(
            [found[j] for j in around], [timings[j] for j in around], errors=errors
        )
        c = cont[around.index(k)]
        both = (np.abs(g[:, 0]) >= lo) & (np.abs(c) >= lo)
        both &= ~_turning(found[k], k, around, timings, model)
        n = int(both.sum())
        a = int(np.sum(both & (np.sign(g[:, 0]) == np.sign(c))))
        decisive, agree = decisive + n, agree + a
        if n >= MIN_PAIRS and a < params.direction_frame_agree * n:
            bad.append(k)
    status = direction_status(agree, decisive, bool(bad), params, axes_known)
    return GyroDirection(status, decisive, agree, len(sample), bad)


def direction_status(
    agree: int, decisive: int, frame_against: bool, params: OrientationParams, axes_known: bool
) -> str:
    """The check's ``status`` from the sample's ``agree`` of ``decisive`` pairs and whether a
    sampled frame ran against the gyro (``frame_against``): ``contradicted`` where one did, or
    where the sample agrees below ``params.direction_session_agree`` by more than chance
    explains (:func:`session_below`); ``consistent`` from that fraction on; otherwise (fewer
    than twice :data:`MIN_PAIRS` pairs, or below the fraction as chance would be) the images do
    not decide: ``undetermined``, or ``unconfirmed`` where the axes are a guess
    (``axes_known`` false)."""
    undecided = "undetermined" if axes_known else "unconfirmed"
    if frame_against:
        return "contradicted"
    if decisive < 2 * MIN_PAIRS:
        return undecided
    level = params.direction_session_agree
    if session_below(agree, decisive, level):
        return "contradicted"
    return "consistent" if agree >= level * decisive else undecided


def session_below(agree: int, decisive: int, level: float) -> bool:
    """Does an agreement of ``agree`` of ``decisive`` pairs lie below the fraction ``level`` by
    more than :data:`DECIDE_SIGMAS` binomial standard errors (``sqrt(level (1 - level) / n)``)?
    False for no pairs."""
    if decisive <= 0:
        return False
    se = float(np.sqrt(level * (1.0 - level) / decisive))
    return agree / decisive < level - DECIDE_SIGMAS * se


def _turning(
    fs: FrameStreaks, k: int, around: list[int], timings: list[FrameTiming], model: Any
) -> np.ndarray:
    """``(N,)`` bool: the streaks of frame ``k`` (``fs``) whose predicted motion turns back
    within their exposure or in the gap between its exposure and a neighbour's in ``around``
    (positions in ``timings``): two image velocities at an obtuse angle, any two of the
    exposure's :data:`TURN_SAMPLES` samples' steps, or over the last :data:`GAP_TANGENT_FRACTION` of
    the earlier exposure and the first of the later one. Each streak's row exposes at its own
    time (the readout), in both frames alike. All False where the model does not cover the
    times."""
    n = len(fs)
    if n == 0:
        return np.zeros(0, bool)
    cam = model.camera
    row = cam.readout_s * np.clip(fs.time_mid[:, 1], 0, cam.height - 1) / cam.height
    own = timings[k]
    t_ref = own.t_s + row + 0.5 * own.exposure_s
    spans = [own.t_s + row[:, None] + np.linspace(0.0, own.exposure_s, TURN_SAMPLES)[None, :]]
    for j in around:
        if j == k:
            continue
        early, late = (timings[j], timings[k]) if j < k else (timings[k], timings[j])
        end = early.t_s + early.exposure_s + row
        start = late.t_s + row
        spans.append(
            np.stack(
                [
                    end - GAP_TANGENT_FRACTION * early.exposure_s,
                    end,
                    start,
                    start + GAP_TANGENT_FRACTION * late.exposure_s,
                ],
                axis=1,
            )
        )
    try:
        tracks = [model.point_track_ordered(fs.time_mid, t_ref, t) for t in spans]
    except CoverageError:
        return np.zeros(n, bool)
    steps = np.diff(tracks[0], axis=1)  # (N, TURN_SAMPLES - 1, 2)
    # Any two of the exposure's velocities, not only successive ones: a gradual turn back
    # rotates the velocity by less than a right angle from step to step.
    turns = np.any(np.einsum("nid,njd->nij", steps, steps) < 0, axis=(1, 2))
    for track in tracks[1:]:
        into, out_of = track[:, 1] - track[:, 0], track[:, 3] - track[:, 2]
        turns |= np.sum(into * out_of, axis=1) < 0
    return turns
