"""The gyro's stages of detecting a session
(:func:`blurtrack.detect.session.pipeline.detect_session`, after every frame's first pass): the
time-shift scan and the readout order, the gyro's direction against the images, the session
calibration, the template pass with the gyro cues, and the gyro's check of the ``quality_ok``
ends, with the continuity cue computed meanwhile.

First, whether the gyro moves the dots as far as the images show
(:mod:`blurtrack.detect.gyro.motion`). A gyro they contradict (a stream of zeros, rates in the
wrong units, another device's gyro) is not used, and no streak is ``quality_ok``: calibration
needs that gyro, and the images alone cannot see a dot's path turn back within the exposure
(``--gyro off`` asks for their verdict); ``--gyro on`` stops with the one-line reason."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from blurtrack.detect.forkmap import Jobs, fork_call
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.direction import GyroDirection, gyro_direction
from blurtrack.detect.gyro.gyrotrust import check_frames
from blurtrack.detect.gyro.motion import GyroMotion, gyro_motion
from blurtrack.detect.gyro.readout import ReadoutOrder, readout_order
from blurtrack.detect.gyro.refinepass import TemplatePass, refine_frames
from blurtrack.detect.gyro.sessionframes import SessionFrames
from blurtrack.detect.gyro.sessionmodel import (
    covered_frames,
    session_calibration,
    session_model,
)
from blurtrack.detect.gyro.timeshift import estimate_timeshift
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session import cues as session_cues
from blurtrack.detect.session.orientation import CUE_SUBSTEP_S, FrameTiming, cue_errors
from blurtrack.errors import CoverageError, DetectionError


class TurnFramesSignal(Exception):  # noqa: N818 - a signal to detect_session, not an error
    """Raised by :func:`gyro_stages` where the frames read the bottom row first
    (:mod:`blurtrack.detect.gyro.readout`); :func:`detect_session` then detects again in the
    frames turned by 180 degrees."""

    def __init__(self, order: ReadoutOrder) -> None:
        super().__init__(order.status)
        self.order = order


def _count_ok(frames: list[FrameStreaks]) -> int:
    """The frames' ``quality_ok`` streaks as they stand (none where not computed)."""
    return sum(int(np.count_nonzero(fs.quality[2])) for fs in frames if fs.quality is not None)


@dataclass
class GyroOutcome:
    """What the gyro's stages found and did (:func:`gyro_stages`; as here where the session
    has no gyro or it is off): the blur model of the frames, the time-shift scan, its
    refinement and the session calibration's fit, the gyro's direction and the readout
    order, the template pass, the frames the gyro does not cover (indices), the frames it
    checked, the change in ``quality_ok`` by the check, and the continuity cues' jobs where
    the check's workers computed them."""

    model: Any = None
    shift: Any = None
    refined: Any = None
    session_fit: Any = None
    direction: GyroDirection | None = None
    order: ReadoutOrder | None = None
    template_pass: TemplatePass = field(default_factory=TemplatePass)
    uncovered: list[int] = field(default_factory=list)
    checked: int = 0
    ok_change: int = 0  # quality_ok streaks after the gyro's check less before
    continued: Jobs | None = None
    #: The gyro's motion against the images' (:mod:`blurtrack.detect.gyro.motion`; None: not
    #: measured), and the ``quality_ok`` streaks refused where the two disagree.
    motion: GyroMotion | None = None
    motion_refused: int = 0


def gyro_stages(
    frames: SessionFrames,
    inputs: tuple[Any, Any],
    up: Any,
    gyro: str,
    refine_timeshift: bool,
) -> tuple[GyroOutcome, list[np.ndarray]]:
    """The gyro's stages over the first pass's ``frames`` (their streaks changed in place by
    the template pass and the check): the time-shift scan and the readout order, the gyro's
    direction, the session calibration, the template pass with the gyro cues, and the
    check. ``inputs``: the session's initial calibration and gyro trace; ``up``: the trace
    resampled. Returns what they did and the frames' cue columns ``(N, 3)`` (the gyro's
    two filled where it covers the frame; the continuity cue's still 0)."""
    from blurtrack.geometry.blur_model import BlurModel

    found, idx, p = frames.found, frames.idx, frames.params
    g = GyroOutcome()
    calib, trace = inputs
    g.motion = gyro_motion(found, frames.timings, calib, up, p)
    if g.motion is not None and not g.motion.agrees:
        # A gyro that does not move the dots as the images show (dead, wrong units, another
        # device's): nothing of it is used, and no streak is quality_ok (module text).
        if gyro == "on":
            raise DetectionError(g.motion.message())
        g.motion_refused = _refuse_all(found)
        return g, [np.zeros((len(fs), 3)) for fs in found]
    g.shift, g.order = _scan(frames, calib, trace, up, refine_timeshift)
    found_shift = g.shift is not None and g.shift.status == "found"
    if found_shift:
        calib = calib.with_(timeshift_cam_imu_s=g.shift.timeshift_s)
    model = BlurModel(calib, up, max_substep_s=CUE_SUBSTEP_S, gyro_upsample=1)
    error_model = cue_errors(p.orientation, refined=found_shift)
    covered = covered_frames(found, frames.timings, model)
    g.direction, early_fit = _direction_and_fit(frames, covered, model, error_model, found_shift)
    set_aside = g.direction is not None and not g.direction.usable
    if set_aside:
        assert g.direction is not None  # set_aside implies a direction
        if gyro == "on":
            raise DetectionError(g.direction.message(idx, refused=True))
        covered, found_shift = [], False  # the images alone from here (module text)
    if found_shift:
        model, covered, g.session_fit, g.refined = session_model(
            frames, covered, model, None if early_fit is None else early_fit()
        )
    g.model = model
    fitted = g.session_fit is not None and g.session_fit.status == "fitted"
    for k in sorted(set(range(len(found))) - set(covered)):
        if len(found[k]) == 0 or set_aside:
            continue  # no streaks, or a gyro set aside, not one that falls short
        if gyro == "on":
            raise CoverageError(f"frame {idx[k]}: the gyro does not cover its exposure")
        g.uncovered.append(idx[k])
    g.template_pass, cues = _template_pass(frames, covered, model, error_model, fitted)
    llrs = [np.zeros((len(fs), 3)) for fs in found]
    for k, llr in zip(covered, cues, strict=True):
        if llr is None:
            if gyro == "on":
                raise CoverageError(f"frame {idx[k]}: the gyro does not cover its exposure")
            g.uncovered.append(idx[k])
        else:
            llrs[k][:, 0:2] = llr
    g.uncovered.sort()
    if found_shift:
        # The gyro's per-frame check of the quality_ok ends, where the time-shift scan
        # found the gyro explaining the streaks (a zero or unrelated gyro predicts nothing).
        g.checked, g.ok_change, g.continued = _check(
            frames, covered, model, llrs, fitted, g.template_pass, calib
        )
    return g, llrs


def _refuse_all(found: list[FrameStreaks]) -> int:
    """Every ``quality_ok`` streak of ``found`` refused (``gyro_mismatch``: its vector is off
    the gyro's, which contradicts the images'); how many were."""
    refused = 0
    for fs in found:
        if fs.quality is None:
            continue
        ok = np.asarray(fs.quality[2], bool)
        refused += int(np.count_nonzero(ok))
        reason = np.asarray(fs.quality[4], object).copy()
        reason[ok] = "gyro_mismatch"
        fs.set_verdict(np.zeros_like(ok), reason)
        fs.one_doubt = np.zeros(len(fs), bool)
    return refused


def _scan(
    frames: SessionFrames, calib: Any, trace: Any, up: Any, refine_timeshift: bool
) -> tuple[Any, ReadoutOrder | None]:
    """The time-shift scan (None where not asked for) and which row the sensor reads first
    (None where not checked). Raises :class:`TurnFramesSignal` where the frames read the
    bottom row first."""
    found, timings, p = frames.found, frames.timings, frames.params
    shift = (
        estimate_timeshift(found, timings, calib, trace, model_gyro=up, params=p)
        if refine_timeshift
        else None
    )
    order: ReadoutOrder | None = None
    if shift is not None and p.timeshift.readout_order_check:
        # Which row the sensor reads first, from the frames (gyro/readout.py); also where
        # the scan found no shift: the other order may.
        order = readout_order(found, timings, calib, trace, shift, model_gyro=up, params=p)
        if not order.usable:
            raise TurnFramesSignal(order)  # detect_session turns the frames
    return shift, order


def _direction_and_fit(
    frames: SessionFrames, covered: list[int], model: Any, error_model: Any, found_shift: bool
) -> tuple[GyroDirection | None, Callable[[], Any] | None]:
    """The gyro's direction against the images (None where not checked) and, where it was
    checked in a forked process, the session calibration's fit made meanwhile
    (:func:`session_calibration`; its errors raised where it is asked for; None: not made,
    :func:`session_model` fits where the gyro stays in use). The fit does not read the
    direction, and is used only where the direction leaves the gyro in use: it runs beside
    the check only where there are workers and the scan found the shift."""
    p = frames.params
    if not p.orientation.direction_check:
        return None, None
    check = partial(
        gyro_direction,
        frames.found,
        frames.timings,
        covered,
        model,
        error_model,
        p.orientation,
        axes_known=frames.session.meta.imu.axes_known,
    )
    beside = found_shift and p.gyro_pass.session_calibration and bool(covered)
    if not (beside and frames.workers > 1):
        return check(), None
    direction = fork_call(check)
    early_fit = fork_call(partial(session_calibration, frames, covered, model), fork=False)
    return direction(), early_fit


def _template_pass(
    frames: SessionFrames, covered: list[int], model: Any, error_model: Any, fitted: bool
) -> tuple[TemplatePass, list[np.ndarray | None]]:
    """The second pass (the gyro's predicted shape as the template; ``frames.found`` changed
    in place), where asked for and the gyro covers a frame, and the gyro cues of the
    ``covered`` frames (``(N, 2)`` each; None for a frame the gyro does not cover after
    all)."""
    found, timings, p = frames.found, frames.timings, frames.params
    template_pass = TemplatePass()  # empty where the pass does not run
    cues: list[np.ndarray | None] | None = None
    if p.gyro_template and covered:
        # The gyro cues of the first-pass frames, batch by batch in the pass's workers
        # ahead of its frames (with one worker: before the pass, so that the table does
        # not depend on the count); after the pass only the frames it changed are
        # computed again.
        first = list(found)
        early = session_cues.cue_jobs(first, timings, covered, model, error_model)
        # Where the session's calibration was corrected, the curves are the dots': no
        # rotations and scales to search (the search stands in for a nominal calibration).
        p_pass = replace(p, gyro_pass=replace(p.gyro_pass, shape_search=False)) if fitted else p
        template_pass = refine_frames(replace(frames, params=p_pass), covered, model, early, fitted)
        got = session_cues.cues_of_jobs(early, first, timings, covered, model, error_model)
        if got is not None:
            cues = session_cues.recomputed_where_changed(
                got, first, found, timings, covered, model, error_model
            )
    if cues is None:
        cues = session_cues.gyro_llrs(found, timings, covered, model, error_model)
    return template_pass, cues


def _check(
    frames: SessionFrames,
    covered: list[int],
    model: Any,
    llrs: list[np.ndarray],
    fitted: bool,
    template_pass: TemplatePass,
    nominal: Any,
) -> tuple[int, int, Jobs]:
    """The gyro's check of the ``quality_ok`` ends (``frames.found``'s quality changed in
    place): its predictions and the continuity cues in the workers, its fit here meanwhile
    (the check changes only the frames' quality, which continuity does not read;
    ``nominal``: the calibration before the session's fit, the centre of its prior on the
    gyro's scale terms). Returns the frames checked, the change in ``quality_ok`` and the
    continuity cues' jobs (done)."""
    found, timings, p, workers = frames.found, frames.timings, frames.params, frames.workers
    image_ok = _count_ok(found)
    # Where the session's calibration was fitted and the template pass changed no frame,
    # the model is already fitted over the very streaks the check would fit.
    unchanged = not template_pass.frames.get("refined")
    # In a part per worker (the same columns as all at once).
    ranges = session_cues.continuity_parts(len(found), workers)
    continued = Jobs([partial(continuity, found, timings, llrs, p, r) for r in ranges])
    checked = check_frames(
        found,
        timings,
        covered,
        model,
        p.source,
        workers,
        known=template_pass.curves,
        fitted=fitted and unchanged,
        jobs=continued,
        nominal=nominal,
    )
    return checked, _count_ok(found) - image_ok, continued


def continuity(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    llrs: list[np.ndarray],
    p: DetectParams,
    part: range | None = None,
) -> list[np.ndarray]:
    """The continuity cue's column of the frames ``part`` (all: None), from the final
    frames and their gyro cues (``llrs``' first two columns)."""
    return session_cues.continuity_columns(
        found, timings, llrs, cue_errors(p.orientation, refined=False), part
    )
