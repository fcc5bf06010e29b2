"""Detection over a whole session: every frame, start/end resolution, the streak table."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.allocator import keep_heap
from blurtrack.detect import sessioncues
from blurtrack.detect.forkmap import Jobs, fork_map, one_blas_thread
from blurtrack.detect.frame import FrameStreaks, detect_frame
from blurtrack.detect.gyro.direction import GyroDirection, gyro_direction
from blurtrack.detect.gyro.gyrotrust import check_frames
from blurtrack.detect.gyro.readout import (
    ReadoutOrder,
    TurnedSession,
    readout_order,
    turned_frame,
    turned_table,
)
from blurtrack.detect.gyro.refinepass import TemplatePass, refine_frames
from blurtrack.detect.gyro.sessionmodel import covered_frames, session_model
from blurtrack.detect.orientation import (
    CUE_SUBSTEP_S,
    FrameTiming,
    combine,
    cue_errors,
)
from blurtrack.detect.params import DetectParams
from blurtrack.detect.separation.quality import REASONS, frame_quality
from blurtrack.detect.table import TABLE_VERSION, build_table, frame_columns
from blurtrack.detect.timeshift import estimate_timeshift
from blurtrack.detect.trust import SOURCES
from blurtrack.errors import CoverageError, DetectionError
from blurtrack.geometry.gyro import GYRO_UPSAMPLE

GYRO_MODES = ("auto", "on", "off")


def default_workers() -> int:
    """The CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def detect_frames(
    session: Any,
    idx: list[int],
    params: DetectParams,
    workers: int = 1,
    meanwhile: Callable[[], None] | None = None,
) -> Iterator[FrameStreaks]:
    """Decode and detect the frames ``idx`` of a session, in order, in ``workers`` processes.

    Frames are independent, so the workers' results are exactly those of one process. Workers
    are forked (:func:`blurtrack.detect.forkmap.fork_map`: they inherit the loaded session,
    nothing is pickled but the results); where the platform cannot fork, or for a single
    worker or frame, the frames are detected here. ``meanwhile``: work of this process that
    does not need the frames (imports, gyro resampling), run while the workers detect (before
    the first frame without workers).
    """

    def one(i: int) -> FrameStreaks:
        fs = detect_frame(session.read_image(i), params)
        # a per-frame stage: here, in parallel
        fs.quality, fs.one_doubt = frame_quality(fs, params)
        return fs

    # Small chunks: the results come back in order, the first ones early.
    chunk = max(1, min(4, len(idx) // (8 * max(1, min(workers, len(idx))))))
    return fork_map(one, idx, workers, chunk, meanwhile)


@dataclass
class DetectionResult:
    """The streak table and what happened on the way.

    ``summary``: frames, streaks, frames without streaks (indices), frames whose exposure the
    gyro did not cover, orientation sources and confidence, hot pixels, flags counts.
    """

    table: pd.DataFrame
    summary: dict[str, Any] = field(default_factory=dict)
    frames: list[FrameStreaks] = field(default_factory=list)


def _gyro_inputs(session: Any, mode: str) -> tuple[Any, Any] | None:
    """The session's initial calibration and gyro trace, or None (mode off / no IMU data)."""
    if mode == "off":
        return None
    if session.imu_t_ns is None or len(session.imu_t_ns) < 2:
        if mode == "on":
            raise CoverageError("--gyro on, but the session has no gyro samples")
        return None
    return session.initial_calibration(), session.gyro()


def _count_ok(frames: list[FrameStreaks]) -> int:
    """The frames' ``quality_ok`` streaks as they stand (none where not computed)."""
    return sum(int(np.count_nonzero(fs.quality[2])) for fs in frames if fs.quality is not None)


def _nan_median(x: pd.Series) -> float | None:
    v = x.to_numpy(float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def _shift_status(model: Any, shift: Any, searched: bool) -> str:
    """``found`` / ``undetermined`` (flat cost) / ``not searched`` / ``too few streaks`` /
    ``no gyro``: what became of the time-shift scan."""
    if model is None:
        return "no gyro"
    if not searched:
        return "not searched"
    return "too few streaks" if shift is None else str(shift.status)


def detect_session(
    session: Any,
    params: DetectParams | None = None,
    gyro: str = "auto",
    frames: range | None = None,
    on_frame: Callable[[int, FrameStreaks], None] | None = None,
    refine_timeshift: bool = True,
    workers: int = 1,
    meanwhile: Callable[[], None] | None = None,
) -> DetectionResult:
    """Detect and orient the streaks of every frame of a loaded session.

    Args:
        session: a :class:`blurtrack.io.session.Session`.
        params: detection parameters.
        gyro: ``auto`` (use the gyro for frames it covers, and report the others), ``on``
            (every frame must be covered: :class:`CoverageError` otherwise), ``off``.
        frames: subset of frame indices (default: all).
        on_frame: progress callback ``(index, streaks)``.
        workers: processes that decode and detect frames in parallel (1: in this process);
            the result does not depend on it.
        refine_timeshift: before using the gyro, scan the camera-IMU time shift around the
            session's guess (:mod:`blurtrack.detect.timeshift`); the guess may be off by more
            than an exposure.
        meanwhile: the caller's own preparation (say, importing the table writer), run while
            the workers detect.
    Raises:
        DetectionError: no streak in any frame.
    """
    # One BLAS thread: the cores are this function's processes' (forkmap.one_blas_thread).
    with one_blas_thread():
        try:
            return _detect_session(
                session, params, gyro, frames, on_frame, refine_timeshift, workers, meanwhile
            )
        except _TurnFramesSignal as turn:
            # The sensor reads the bottom row first: detect in the frames turned by 180
            # degrees, where it reads the top row first, and turn the result back.
            p = params or DetectParams()
            once = replace(p, timeshift=replace(p.timeshift, readout_order_check=False))
            res = _detect_session(
                TurnedSession(session), once, gyro, frames, None, refine_timeshift, workers, None
            )
            res.summary["gyro_readout_order"] = turn.order.as_dict()
            return DetectionResult(
                turned_table(res.table, session.meta.camera.resolution),
                res.summary,
                [turned_frame(fs) for fs in res.frames],
            )


class _TurnFramesSignal(Exception):  # noqa: N818 - a signal within this module, not an error
    """Raised by :func:`_detect_session` where the frames read the bottom row first
    (:mod:`blurtrack.detect.gyro.readout`); :func:`detect_session` then detects again in the
    frames turned by 180 degrees."""

    def __init__(self, order: ReadoutOrder) -> None:
        super().__init__(order.status)
        self.order = order


def _detect_session(
    session: Any,
    params: DetectParams | None,
    gyro: str,
    frames: range | None,
    on_frame: Callable[[int, FrameStreaks], None] | None,
    refine_timeshift: bool,
    workers: int,
    meanwhile: Callable[[], None] | None,
) -> DetectionResult:
    """:func:`detect_session`'s work, stage by stage: the frames' first pass, the gyro's
    stages (where the session has a gyro), the continuity cue, orientation and the table."""
    if gyro not in GYRO_MODES:
        raise DetectionError(f"gyro mode must be one of {GYRO_MODES}, got {gyro!r}")
    p = params or DetectParams()
    # Here too, not only where frames are detected: with workers this process still runs the
    # scan, the gyro cues and continuity over ~20 000-streak arrays, whose freed blocks
    # glibc would otherwise unmap and fault in again (the cues: ~3x the arithmetic's time).
    keep_heap()
    n_frames = len(session.frames)
    idx = list(frames if frames is not None else range(n_frames))
    if not idx:
        raise DetectionError("the session has no frames")
    t_s = session.frame_times_s
    exp_s = session.exposures_s
    timings = [FrameTiming(float(t_s[i]), float(exp_s[i])) for i in idx]
    inputs = _gyro_inputs(session, gyro)
    found, up = _first_pass(session, idx, p, workers, on_frame, inputs, meanwhile)
    g = _GyroOutcome()
    llrs = [np.zeros((len(fs), 3)) for fs in found]
    if inputs is not None:
        assert up is not None  # resampled while the workers detected
        g, llrs = _gyro_stages(
            session, found, timings, idx, inputs, up, p, gyro, refine_timeshift, workers
        )
    columns = (
        [c for got in g.continued.results for c in got]
        if g.continued is not None
        else _continuity(found, timings, llrs, p)
    )
    for llr, col in zip(llrs, columns, strict=True):
        llr[:, 2] = col
    table, sources, allc = _oriented_table(session, found, idx, llrs)
    empty = [idx[k] for k, fs in enumerate(found) if len(fs) == 0]
    over = p.quality.overexposed_fraction
    overexposed = [idx[k] for k, fs in enumerate(found) if fs.saturated_fraction > over]
    if len(table) == 0:
        why = f" ({len(overexposed)} over-exposed)" if overexposed else ""
        raise DetectionError(f"no laser-dot streaks found in any of the {len(idx)} frames{why}")
    summary = _summary(
        table,
        found,
        idx,
        p,
        g,
        gyro=gyro,
        initial_timeshift_s=None if inputs is None else float(inputs[0].timeshift_cam_imu_s),
        refine_timeshift=refine_timeshift,
        empty=empty,
        overexposed=overexposed,
        sources=sources,
        confidence=allc,
    )
    return DetectionResult(table=table, summary=summary, frames=found)


def _first_pass(
    session: Any,
    idx: list[int],
    p: DetectParams,
    workers: int,
    on_frame: Callable[[int, FrameStreaks], None] | None,
    inputs: tuple[Any, Any] | None,
    meanwhile: Callable[[], None] | None,
) -> tuple[list[FrameStreaks], Any]:
    """Every frame of ``idx`` detected from its image alone (:func:`detect_frames`), in
    order, and the gyro trace of ``inputs`` resampled meanwhile (None without ``inputs``)."""
    resampled: list[Any] = []

    def prepare() -> None:
        # The gyro resampled once (the scan and the cues use the same model trace).
        if inputs is not None:
            resampled.append(inputs[1].upsampled(GYRO_UPSAMPLE))
        if meanwhile is not None:
            meanwhile()

    found: list[FrameStreaks] = []
    frames_iter = detect_frames(session, idx, p, workers, prepare)
    for i, fs in zip(idx, frames_iter, strict=True):
        found.append(fs)
        if on_frame is not None:
            on_frame(i, fs)
    return found, (resampled[0] if resampled else None)


@dataclass
class _GyroOutcome:
    """What the gyro's stages found and did (:func:`_gyro_stages`; as here where the session
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


def _gyro_stages(
    session: Any,
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    idx: list[int],
    inputs: tuple[Any, Any],
    up: Any,
    p: DetectParams,
    gyro: str,
    refine_timeshift: bool,
    workers: int,
) -> tuple[_GyroOutcome, list[np.ndarray]]:
    """The gyro's stages over the first pass's frames ``found`` (changed in place by the
    template pass and the check): the time-shift scan and the readout order, the gyro's
    direction, the session calibration, the template pass with the gyro cues, and the
    check. ``inputs``: the session's initial calibration and gyro trace; ``up``: the trace
    resampled. Returns what they did and the frames' cue columns ``(N, 3)`` (the gyro's
    two filled where it covers the frame; the continuity cue's still 0)."""
    from blurtrack.geometry.blur_model import BlurModel

    g = _GyroOutcome()
    calib, trace = inputs
    g.shift, g.order = _scan(found, timings, calib, trace, up, p, refine_timeshift)
    found_shift = g.shift is not None and g.shift.status == "found"
    if found_shift:
        calib = calib.with_(timeshift_cam_imu_s=g.shift.timeshift_s)
    model = BlurModel(calib, up, max_substep_s=CUE_SUBSTEP_S, gyro_upsample=1)
    error_model = cue_errors(p.orientation, refined=found_shift)
    covered = covered_frames(found, timings, model)
    if p.orientation.direction_check:
        g.direction = gyro_direction(
            found,
            timings,
            covered,
            model,
            error_model,
            p.orientation,
            axes_known=session.meta.imu.axes_known,
        )
    set_aside = g.direction is not None and not g.direction.usable
    if set_aside:
        assert g.direction is not None  # set_aside implies a direction
        if gyro == "on":
            raise DetectionError(g.direction.message(idx, refused=True))
        covered, found_shift = [], False  # the images alone from here (module text)
    if found_shift:
        model, covered, g.session_fit, g.refined = session_model(
            session, found, timings, idx, covered, model, p, workers
        )
    g.model = model
    fitted = g.session_fit is not None and g.session_fit.status == "fitted"
    for k in sorted(set(range(len(found))) - set(covered)):
        if len(found[k]) == 0 or set_aside:
            continue  # no streaks, or a gyro set aside, not one that falls short
        if gyro == "on":
            raise CoverageError(f"frame {idx[k]}: the gyro does not cover its exposure")
        g.uncovered.append(idx[k])
    g.template_pass, cues = _template_pass(
        session, found, timings, idx, covered, model, error_model, p, fitted, workers
    )
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
            found, timings, covered, model, llrs, p, fitted, g.template_pass, workers
        )
    return g, llrs


def _scan(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    calib: Any,
    trace: Any,
    up: Any,
    p: DetectParams,
    refine_timeshift: bool,
) -> tuple[Any, ReadoutOrder | None]:
    """The time-shift scan (None where not asked for) and which row the sensor reads first
    (None where not checked). Raises :class:`_TurnFramesSignal` where the frames read the
    bottom row first."""
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
            raise _TurnFramesSignal(order)  # detect_session turns the frames
    return shift, order


def _template_pass(
    session: Any,
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    idx: list[int],
    covered: list[int],
    model: Any,
    error_model: Any,
    p: DetectParams,
    fitted: bool,
    workers: int,
) -> tuple[TemplatePass, list[np.ndarray | None]]:
    """The second pass (the gyro's predicted shape as the template; ``found`` changed in
    place), where asked for and the gyro covers a frame, and the gyro cues of the
    ``covered`` frames (``(N, 2)`` each; None for a frame the gyro does not cover after
    all)."""
    template_pass = TemplatePass()  # empty where the pass does not run
    cues: list[np.ndarray | None] | None = None
    if p.gyro_template and covered:
        # The gyro cues of the first-pass frames, batch by batch in the pass's workers
        # ahead of its frames (with one worker: before the pass, so that the table does
        # not depend on the count); after the pass only the frames it changed are
        # computed again.
        first = list(found)
        early = sessioncues.cue_jobs(first, timings, covered, model, error_model)
        # Where the session's calibration was corrected, the curves are the dots': no
        # rotations and scales to search (the search stands in for a nominal calibration).
        p_pass = replace(p, gyro_pass=replace(p.gyro_pass, shape_search=False)) if fitted else p
        template_pass = refine_frames(
            session, found, timings, idx, covered, model, p_pass, workers, early
        )
        got = sessioncues.cues_of_jobs(early, first, timings, covered, model, error_model)
        if got is not None:
            cues = sessioncues.recomputed_where_changed(
                got, first, found, timings, covered, model, error_model
            )
    if cues is None:
        cues = sessioncues.gyro_llrs(found, timings, covered, model, error_model)
    return template_pass, cues


def _check(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    llrs: list[np.ndarray],
    p: DetectParams,
    fitted: bool,
    template_pass: TemplatePass,
    workers: int,
) -> tuple[int, int, Jobs]:
    """The gyro's check of the ``quality_ok`` ends (``found``'s quality changed in place):
    its predictions and the continuity cues in the workers, its fit here meanwhile (the
    check changes only the frames' quality, which continuity does not read). Returns the
    frames checked, the change in ``quality_ok`` and the continuity cues' jobs (done)."""
    image_ok = _count_ok(found)
    # Where the session's calibration was fitted and the template pass changed no frame,
    # the model is already fitted over the very streaks the check would fit.
    unchanged = not template_pass.frames.get("refined")
    # In a part per worker (the same columns as all at once).
    ranges = sessioncues.continuity_parts(len(found), workers)
    continued = Jobs([partial(_continuity, found, timings, llrs, p, r) for r in ranges])
    checked = check_frames(
        found,
        timings,
        covered,
        model,
        p.source,
        workers,
        None,
        template_pass.curves,
        fitted=fitted and unchanged,
        jobs=continued,
    )
    return checked, _count_ok(found) - image_ok, continued


def _continuity(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    llrs: list[np.ndarray],
    p: DetectParams,
    part: range | None = None,
) -> list[np.ndarray]:
    """The continuity cue's column of the frames ``part`` (all: None), from the final
    frames and their gyro cues (``llrs``' first two columns)."""
    return sessioncues.continuity_columns(
        found, timings, llrs, cue_errors(p.orientation, refined=False), part
    )


def _oriented_table(
    session: Any, found: list[FrameStreaks], idx: list[int], llrs: list[np.ndarray]
) -> tuple[pd.DataFrame, dict[str, int], np.ndarray]:
    """Each frame's streaks turned to their start first by its cues (``llrs``, the frames
    changed in place), the streak table, the count of each orientation source and every
    streak's orientation confidence."""
    parts = []
    stamps = session.frames["timestamp_ns"].to_numpy(np.int64)
    sources: dict[str, int] = {}
    conf: list[np.ndarray] = []
    for k, fs in enumerate(found):
        ori = combine(llrs[k])
        fs.reverse(ori.swap)
        parts.append(frame_columns(idx[k], int(stamps[idx[k]]), fs, ori))
        for s in ori.source:
            sources[s] = sources.get(s, 0) + 1
        conf.append(ori.confidence)
    return build_table(parts), sources, np.concatenate(conf)


def _summary(
    table: pd.DataFrame,
    found: list[FrameStreaks],
    idx: list[int],
    p: DetectParams,
    g: _GyroOutcome,
    *,
    gyro: str,
    initial_timeshift_s: float | None,
    refine_timeshift: bool,
    empty: list[int],
    overexposed: list[int],
    sources: dict[str, int],
    confidence: np.ndarray,
) -> dict[str, Any]:
    """The session's summary (:class:`DetectionResult`)."""
    model, shift, session_fit, template_pass = g.model, g.shift, g.session_fit, g.template_pass
    reasons = {r: int((table["reason"] == r).sum()) for r in REASONS}
    demoted = reasons["hairpin"] + reasons["gyro_mismatch"]
    return {
        "frames": len(idx),
        "streaks": len(table),
        "frames_without_streaks": empty,
        "frames_without_gyro": g.uncovered,
        "frames_overexposed": overexposed,
        "gyro": "off" if model is None else gyro,
        "gyro_timeshift_initial_s": initial_timeshift_s,
        "gyro_timeshift_s": None
        if shift is None or shift.status != "found" or model is None
        else float(model.calib.timeshift_cam_imu_s),
        "gyro_timeshift_scan_s": None if shift is None else shift.timeshift_s,
        "gyro_timeshift_refinement": "session calibration"
        if session_fit is not None and session_fit.status == "fitted"
        else "not run"
        if g.refined is None
        else g.refined.status,
        "gyro_readout_s": None if model is None else float(model.camera.readout_s),
        "gyro_timeshift_status": _shift_status(model, shift, refine_timeshift),
        "gyro_direction": None if g.direction is None else g.direction.as_dict(idx),
        "gyro_readout_order": None if g.order is None else g.order.as_dict(),
        "gyro_session_calibration": None
        if session_fit is None
        else {
            "status": session_fit.status,
            "voters": session_fit.voters,
            "residual_before_px": session_fit.residual_before_px,
            "residual_after_px": session_fit.residual_after_px,
            "change": session_fit.change,
        },
        "gyro_template_frames": template_pass.frames,
        "gyro_template_components": {
            "candidates": template_pass.candidates,
            "replaced": template_pass.replaced,
            "streaks": template_pass.streaks,
        },
        "orientation_sources": sources,
        "orientation_confidence_median": float(np.median(confidence)),
        "orientation_confident_fraction": float(np.mean(confidence >= 0.9)),
        "flags": {
            c: int(table[c].sum())
            for c in ("clipped", "saturated", "merged", "crossing", "looped", "faint")
        },
        "hot_pixels": int(sum(fs.hot_pixels for fs in found)),
        "light_colour": _light_colour(found, idx),
        "table_version": TABLE_VERSION,
        "quality_ok": int(table["quality_ok"].sum()),
        "source": {s: int((table["source"] == s).sum()) for s in SOURCES},
        "reasons": reasons,
        "gyro_trust_frames": g.checked,
        # Only the check demotes (its two reasons) or confirms (one doubt lifted, never a
        # demoted streak): confirmed = the change in quality_ok plus the demoted.
        "gyro_trust_demoted": demoted,
        "gyro_trust_confirmed": g.ok_change + demoted,
        "thick_saturated": int(table["thick_saturated"].sum()),
        "shape_deviation_median_px": _nan_median(table["shape_deviation_px"]),
        "median_length_px": float(table["length_px"].median()),
        "params": p.to_dict(),
    }


def _light_colour(found: list[FrameStreaks], idx: list[int]) -> dict[str, Any]:
    """For the summary: the frames measured on the luma of their one-colour light
    (``frames``, the session's frame numbers) and the light's median colour (B, G, R relative
    to its strongest channel; None without such frames)."""
    one = [k for k, fs in enumerate(found) if fs.light_bgr is not None]
    colours = np.array([found[k].light_bgr for k in one], float).reshape(-1, 3)
    return {
        "frames": [idx[k] for k in one],
        "bgr": np.round(np.median(colours, axis=0), 3).tolist() if one else None,
    }
