"""The session's blur model for the gyro's stages of detection: which frames its gyro covers,
and its calibration corrected once the time-shift scan found the shift
(:func:`session_model`: the session calibration, else the template time-shift refinement)."""

from __future__ import annotations

from typing import Any

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.sessionframes import SessionFrames
from blurtrack.detect.session.orientation import FrameTiming


def covered_frames(found: list[FrameStreaks], timings: list[FrameTiming], model: Any) -> list[int]:
    """Positions of the frames with streaks whose exposure ``model``'s gyro covers."""
    return [
        k
        for k, (fs, tm) in enumerate(zip(found, timings, strict=True))
        if len(fs) and covers(model, tm)
    ]


def covers(model: Any, tm: FrameTiming) -> bool:
    """Whether the model's gyro covers a frame's exposure (all rows, camera clock)."""
    shift = float(model.calib.timeshift_cam_imu_s)
    t0 = tm.t_s + shift
    return bool(model.gyro.covers(t0, t0 + model.camera.readout_s + tm.exposure_s))


def session_calibration(frames: SessionFrames, covered: list[int], model: Any) -> Any:
    """The session calibration of :func:`session_model` (None where not asked for or no
    frame is covered; :func:`~blurtrack.detect.gyro.sessioncalib.fit_session_calibration`)."""
    if not (frames.params.gyro_pass.session_calibration and covered):
        return None
    from blurtrack.detect.gyro.sessioncalib import fit_session_calibration

    return fit_session_calibration(frames.found, frames.timings, covered, model)


def session_model(
    frames: SessionFrames, covered: list[int], model: Any, session_fit: Any = None
) -> tuple[Any, list[int], Any, Any]:
    """The blur model the template pass, the cues and the check predict with, once the
    time-shift scan found the shift of ``model``: its calibration corrected by the session's
    error fitted to the first pass's quality_ok streaks (time offset and readout among it;
    :mod:`blurtrack.detect.gyro.sessioncalib`), or where that is not fitted, its shift and
    readout refined by the template pass's predicted curves (:mod:`blurtrack.detect.gyro.shiftfit`).
    ``session_fit``: :func:`session_calibration`'s, where already computed (None: computed
    here). Returns the model, the frames it covers, the session fit and the template
    refinement (None: not run)."""
    from dataclasses import replace as with_calib

    found, timings, p = frames.found, frames.timings, frames.params
    refined = None
    if session_fit is None:
        session_fit = session_calibration(frames, covered, model)
    if session_fit is not None and session_fit.status == "fitted":
        model = with_calib(model, calib=session_fit.calib)
        covered = covered_frames(found, timings, model)
    if p.gyro_template and covered and not (session_fit and session_fit.status == "fitted"):
        from blurtrack.detect.gyro.shiftfit import refine_timeshift as refine_by_templates

        refined = refine_by_templates(
            frames.read_image, found, timings, covered, model, p, frames.workers
        )
        if refined.status == "refined":
            calib = model.calib.with_(
                timeshift_cam_imu_s=refined.timeshift_s, readout_s=refined.readout_s
            )
            model = with_calib(model, calib=calib)
            covered = covered_frames(found, timings, model)
    return model, covered, session_fit, refined
