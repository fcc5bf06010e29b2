"""The session's calibration error, fitted from the first pass's ``quality_ok`` streaks before
the gyro-template pass uses the blur model.

The initial calibration is nominal (intrinsics, ``R_cam_imu`` and the gyro bias are guesses, the
time shift is the scan's), so every predicted curve is off by a px or two, in the same way for
every frame: one error of the session's eleven calibration parameters
(:data:`~blurtrack.detect.gyro.gyrotrust.CALIBRATION_STEPS`: focal length, principal point,
three axis angles, time offset, readout, three gyro-bias rates). The image's ``quality_ok``
streaks measure it: their start-to-end vectors ``m`` against the predicted ``p`` change with
the calibration by ``J d`` (the prediction's Jacobian by finite differences,
:func:`~blurtrack.detect.gyro.gyrotrust.perturbed_models`), ``d`` fitted robustly and
orientation-free (:func:`~blurtrack.detect.gyro.gyrotrust.session_residual`), the calibration
moved by ``d`` and the fit repeated from there (Gauss-Newton: the prediction is nonlinear in
the axes and the bias over a 10-50 ms exposure).

The corrected model predicts the curves the gyro-template pass takes as templates (fewer
rotations and scales to search, and a gate that compares lines with what the dots drew), the
orientation cues and the gyro's check. The endpoints stay the image's: the correction decides
which light is which dot's, and the calibration a lab fits later (``blurtrack calibrate``)
starts again from the streak table and the nominal calibration.

A correction is kept only where it predicts the voters better than the calibration it starts
from (the median residual falls) and no parameter moved by more than
:data:`~blurtrack.detect.gyro.gyrotrust.MAX_FIT_STEPS` of its finite-difference step (20 % of the
focal length, 100 px, 0.2 rad, 20 ms, 0.2 rad/s): a fit that far from its start is outside
the linearisation it came from, and says that the nominal calibration is wrong in kind (axes
mirrored, another camera's gyro), which ``blurtrack calibrate`` decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyrotrust import (
    CALIBRATION_STEPS,
    MAX_FIT_STEPS,
    SESSION_VOTERS_PER_PARAMETER,
    corrected_model,
    fit_sample,
    sample_vectors,
    session_fit,
)
from blurtrack.detect.orientation import FrameTiming
from blurtrack.errors import BlurTrackError
from blurtrack.geometry.rotation import so3_log

#: Gauss-Newton rounds (each: the Jacobian at the current calibration, a robust fit, a move;
#: :func:`~blurtrack.detect.gyro.gyrotrust.session_fit` over the check's sample,
#: :data:`~blurtrack.detect.gyro.gyrotrust.FIT_SAMPLE_VOTERS` at most). Many voters pay: on
#: ``hard`` seed 2 (8 frames, 933 voters) the corrected model's vectors are 0.57 px from the
#: true ones at the median with all of them, 0.79 px with 400 evenly spaced (a few poorly
#: determined combinations of the axes, readout and bias).
ROUNDS = 2
#: Parameter names of ``d``, in the order of the Jacobian's columns.
PARAMETERS = (
    "focal_rel",
    "cx_px",
    "cy_px",
    "axis_x_rad",
    "axis_y_rad",
    "axis_z_rad",
    "timeshift_s",
    "readout_s",
    "bias_x_radps",
    "bias_y_radps",
    "bias_z_radps",
)


@dataclass(frozen=True)
class SessionCalibration:
    """The fit's outcome. ``status``: ``fitted`` (``calib`` corrected), ``too_few_voters``,
    ``no_prediction`` (the gyro misses the voters' exposures), ``not_better`` or
    ``implausible`` (``calib`` as given; module text). ``change``: the correction by
    parameter name (:data:`PARAMETERS`, units in the names; zeros where not fitted; the
    refused one where ``implausible``). ``voters``: streaks used; ``residual_before_px`` /
    ``residual_after_px``: their median vector residual against the given and the
    corrected calibration (NaN where not measured)."""

    status: str
    calib: Any
    change: dict[str, float]
    voters: int
    residual_before_px: float
    residual_after_px: float


def _median_residual(m: np.ndarray, p: np.ndarray) -> float:
    """Median orientation-free ``|m - p|`` (px) over the rows the model predicts."""
    r = np.minimum(np.hypot(*(m - p).T), np.hypot(*(m + p).T))
    r = r[np.isfinite(r)]
    return float(np.median(r)) if r.size else float("nan")


def fit_session_calibration(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
) -> SessionCalibration:
    """The session's calibration error from the ``covered`` frames' ``quality_ok`` streaks
    (see the module text); ``model``: the blur model of the calibration to correct (its
    ``calib``; the corrected one is returned, not a model)."""
    zero = dict.fromkeys(PARAMETERS, 0.0)
    sub = [frames[k] for k in covered]
    tim = [timings[k] for k in covered]
    pos, picks = fit_sample(sub)
    n = sum(len(s) for s in picks)
    if n < SESSION_VOTERS_PER_PARAMETER * len(PARAMETERS):
        return SessionCalibration("too_few_voters", model.calib, zero, n, np.nan, np.nan)
    m = np.concatenate([sub[k].end_b[s] - sub[k].end_a[s] for k, s in zip(pos, picks, strict=True)])
    current = model
    try:
        before = _median_residual(m, sample_vectors(sub, tim, model, pos, picks))
        for _ in range(ROUNDS):
            # No limit per round: the rounds may go far; the whole move is judged below.
            d = session_fit(sub, tim, current, max_steps=None)
            if d is None:
                break
            current = corrected_model(current, d)
        after = _median_residual(m, sample_vectors(sub, tim, current, pos, picks))
    except BlurTrackError:
        return SessionCalibration("no_prediction", model.calib, zero, n, np.nan, np.nan)
    if not np.isfinite(before):
        return SessionCalibration("no_prediction", model.calib, zero, n, before, after)
    change = difference(model.calib, current.calib)
    if not after < before:
        return SessionCalibration("not_better", model.calib, zero, n, before, after)
    if _steps(change) > MAX_FIT_STEPS:
        return SessionCalibration("implausible", model.calib, change, n, before, after)
    return SessionCalibration("fitted", current.calib, change, n, before, after)


def difference(before: Any, after: Any) -> dict[str, float]:
    """``after`` less ``before`` by parameter name (:data:`PARAMETERS`, units in the names;
    the axes as the rotation vector of ``R_after R_before^T``)."""
    f0, _, cx0, cy0 = before.camera.intrinsics
    f1, _, cx1, cy1 = after.camera.intrinsics
    rotvec = so3_log(np.asarray(after.R_cam_imu) @ np.asarray(before.R_cam_imu).T)
    bias = np.asarray(after.gyro_bias_radps, float) - np.asarray(before.gyro_bias_radps, float)
    values = [
        f1 / f0 - 1.0,
        cx1 - cx0,
        cy1 - cy0,
        *rotvec.tolist(),
        after.timeshift_cam_imu_s - before.timeshift_cam_imu_s,
        after.camera.readout_s - before.camera.readout_s,
        *bias.tolist(),
    ]
    return {k: float(v) for k, v in zip(PARAMETERS, values, strict=True)}


def _steps(change: dict[str, float]) -> float:
    """The largest move of :func:`difference`'s ``change`` in units of its parameter's step
    (:data:`~blurtrack.detect.gyro.gyrotrust.CALIBRATION_STEPS`)."""
    step = {"focal_rel": "focal", "cx_px": "pp", "cy_px": "pp", "timeshift_s": "time"}
    step |= {"readout_s": "time"}
    step |= {k: "axes" for k in ("axis_x_rad", "axis_y_rad", "axis_z_rad")}
    step |= {k: "bias" for k in ("bias_x_radps", "bias_y_radps", "bias_z_radps")}
    return max(abs(v) / CALIBRATION_STEPS[step[k]] for k, v in change.items())
