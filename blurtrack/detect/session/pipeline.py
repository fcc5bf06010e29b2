"""Detection over a whole session: every frame, start/end resolution, the streak table."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.allocator import keep_heap
from blurtrack.detect.forkmap import fork_map, one_blas_thread
from blurtrack.detect.frame import FrameStreaks, detect_frame
from blurtrack.detect.gyro.framecheck import tolerances_for
from blurtrack.detect.gyro.gyrostages import GyroOutcome, TurnFramesSignal, continuity, gyro_stages
from blurtrack.detect.gyro.readout import (
    TurnedSession,
    turned_frame,
    turned_table,
)
from blurtrack.detect.gyro.sessionframes import SessionFrames
from blurtrack.detect.params import DetectParams, SourceParams
from blurtrack.detect.separation.quality import REASONS, frame_quality
from blurtrack.detect.session.orientation import (
    FrameTiming,
    combine,
)
from blurtrack.detect.session.table import TABLE_VERSION, build_table, frame_columns
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


def _nan_median(x: pd.Series) -> float | None:
    v = x.to_numpy(float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def _shift_status(model: Any, shift: Any, searched: bool, motion: Any = None) -> str:
    """``found`` / ``undetermined`` (flat cost) / ``not searched`` / ``too few streaks`` /
    ``no gyro`` / ``gyro not used`` (its motion contradicts the images'): what became of the
    time-shift scan."""
    if motion is not None and not motion.agrees:
        return "gyro not used"
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
            session's guess (:mod:`blurtrack.detect.gyro.timeshift`); the guess may be off by more
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
        except TurnFramesSignal as turn:
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
    g = GyroOutcome()
    llrs = [np.zeros((len(fs), 3)) for fs in found]
    if inputs is not None:
        assert up is not None  # resampled while the workers detected
        session_frames = SessionFrames(session, found, timings, idx, p, workers)
        g, llrs = gyro_stages(session_frames, inputs, up, gyro, refine_timeshift)
    columns = (
        [c for got in g.continued.results for c in got]
        if g.continued is not None
        else continuity(found, timings, llrs, p)
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
    g: GyroOutcome,
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
        "gyro": "off" if model is None and g.motion is None else gyro,
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
        "gyro_timeshift_status": _shift_status(model, shift, refine_timeshift, g.motion),
        "gyro_direction": None if g.direction is None else g.direction.as_dict(idx),
        "gyro_motion": None
        if g.motion is None
        else {**g.motion.as_dict(), "refused": g.motion_refused},
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
        **_model_errors(found, idx, p.source),
        "thick_saturated": int(table["thick_saturated"].sum()),
        "shape_deviation_median_px": _nan_median(table["shape_deviation_px"]),
        "median_length_px": float(table["length_px"].median()),
        "params": p.to_dict(),
    }


def _model_errors(found: list[FrameStreaks], idx: list[int], p: SourceParams) -> dict[str, Any]:
    """For the summary: the checked frames' model errors (px; median, 90th percentile and
    largest; None where none was measured) and the frames (session numbers) whose check's
    tolerance fell below ``p.gyro_vector_tol_px`` for it
    (:func:`blurtrack.detect.gyro.framecheck.tolerances_for`)."""
    err = np.array([fs.gyro_model_error_px for fs in found], float)
    have = np.isfinite(err)
    quantiles = None
    if have.any():
        q50, q90 = np.quantile(err[have], [0.5, 0.9])
        quantiles = {"median": float(q50), "p90": float(q90), "max": float(err[have].max())}
    lowered = [
        idx[k]
        for k in np.flatnonzero(have).tolist()
        if tolerances_for(float(err[k]), p).vector_px < p.gyro_vector_tol_px
    ]
    return {"gyro_trust_model_error_px": quantiles, "gyro_trust_lowered_frames": lowered}


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
