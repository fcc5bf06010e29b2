"""Calibration driver: checks, initialisation, coarse-to-fine robust fit, outliers, hold-out.

Stages (each warm-starts the next; one function each in :mod:`calib.stages` and
:mod:`calib.finish`):

1. input checks (enough streaks and frames, gyro coverage, motion);
2. shift/focal search (:mod:`calib.init`);
3. robust LM on a subsample with the shift and focal lengths only, then with every requested
   parameter that the motion makes observable (near-null directions of the information matrix
   are fixed at their initial value, with a warning);
4. robust LM on every training streak (endpoint residuals) or inter-frame track
   (:mod:`calib.tracks`; ``FitOptions.residuals``), with outlier rejection in between: those
   whose error exceeds ``OUTLIER_SIGMAS`` robust sigmas are dropped, except streaks that fit
   once start and end are swapped: they are counted as wrongly oriented, swapped and kept;
5. uncertainty, warnings and hold-out statistics.

Options, constants and helpers live in :mod:`calib.fitcore` and are re-exported here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from calib import finish, stages
from calib.data import StreakSet
from calib.fitcore import (
    FINE_DELTA_SIGMAS,
    MAX_RESIDUAL_SIGMA_PX,
    MIN_FRAMES,
    MIN_INLIER_FRACTION,
    MIN_OUTLIER_PX,
    MIN_STREAKS,
    MIN_TRACK_SHARE,
    OUTLIER_SIGMAS,
    RESIDUALS,
    SCALE_Z,
    SUBSAMPLE,
    FitOptions,
    Progress,
    ProgressFn,
    check_fit_inputs,
    classify,
    outlier_threshold,
    rayleigh_sigma,
    reorient,
    scale_check,
)
from calib.init import InitResult
from calib.params import THETA_NAMES
from calib.result import CalibResult

__all__ = [
    "FINE_DELTA_SIGMAS",
    "MAX_RESIDUAL_SIGMA_PX",
    "MIN_FRAMES",
    "MIN_INLIER_FRACTION",
    "MIN_OUTLIER_PX",
    "MIN_STREAKS",
    "MIN_TRACK_SHARE",
    "OUTLIER_SIGMAS",
    "RESIDUALS",
    "SCALE_Z",
    "SUBSAMPLE",
    "FitOptions",
    "Progress",
    "ProgressFn",
    "calibrate",
    "check_fit_inputs",
    "classify",
    "outlier_threshold",
    "rayleigh_sigma",
    "reorient",
    "scale_check",
]


def calibrate(
    streaks: StreakSet,
    gyro: GyroTrace,
    initial: Calibration,
    options: FitOptions = FitOptions(),  # noqa: B008 (frozen dataclass)
    clock: Callable[[], float] = time.perf_counter,
    progress: ProgressFn | None = None,
) -> CalibResult:
    """Fit the blur model to measured streak endpoints (see the module docstring).

    With a hold-out (``options.holdout_fraction > 0``) and ``options.refit_all``, the fit on
    the training frames is evaluated on the held-out frames, then refitted on every frame
    (:func:`_refit`: the final stage only, warm-started from the training fit's estimate and
    outlier thresholds; the search, the coarse stages, the residual choice and the parameters
    held as unobservable are the training fit's): the returned calibration, values and sigma
    are the refit's, the hold-out statistics those of the training fit
    (``holdout_fit_values``).

    Args:
        streaks: measured streaks, times relative to ``streaks.t0_s``.
        gyro: the session's gyro trace on the absolute IMU clock.
        initial: initial guess (the rig's ``session.yaml``); distortion is kept fixed.
        progress: called with a :class:`Progress` at each stage start and LM iteration.
    """
    t_start = clock()
    rep = stages.Reporter(progress, clock, t_start)
    timings: dict[str, float] = {}
    prep = stages.prepare(streaks, gyro, initial, options)
    ini = stages.initialise(prep, options, rep)
    timings["init"] = clock() - t_start
    co = stages.coarse_fit(prep, ini, options, rep)
    timings["coarse"] = clock() - t_start - timings["init"]
    md = stages.choose_mode(prep, co, options)
    fine = stages.fine_fit(prep, co, md, options, rep)
    res = _finish(prep, ini, co, md, fine, options, timings, clock, t_start)
    if not (options.refit_all and options.holdout_fraction > 0 and res.status != "failed"):
        return res
    full = _refit(prep, ini, co, md, fine, res, options, clock, rep)
    timings = {**res.timings_s, **{f"refit_{k}": v for k, v in full.timings_s.items()}}
    timings["total"] = clock() - t_start
    return replace(
        full,
        holdout=res.holdout,
        holdout_all=res.holdout_all,
        holdout_fit_values=dict(res.values),
        iterations=res.iterations + full.iterations,
        warnings=tuple(dict.fromkeys(res.warnings + full.warnings)),
        timings_s=timings,
    )


def _finish(
    prep: stages.Prepared,
    ini: InitResult,
    co: stages.Coarse,
    md: stages.Mode,
    fine: stages.Fine,
    options: FitOptions,
    timings: dict[str, float],
    clock: Callable[[], float],
    t_start: float,
) -> CalibResult:
    """The optional frame-noise refinement and the result (:mod:`calib.finish`)."""
    for k, n in enumerate(fine.round_iterations):
        timings[f"fine{k}_iterations"] = n
    timings["fine"] = clock() - t_start - sum(timings.get(k, 0.0) for k in ("init", "coarse"))
    gls = finish.frame_noise_fit(prep, co, md, fine) if options.frame_noise else None
    return finish.assemble(prep, ini, co, md, fine, gls, timings, clock, t_start)


def _refit(
    prep: stages.Prepared,
    ini: InitResult,
    co: stages.Coarse,
    md: stages.Mode,
    fine: stages.Fine,
    res: CalibResult,
    options: FitOptions,
    clock: Callable[[], float],
    rep: stages.Reporter,
) -> CalibResult:
    """The final stage again on every frame, warm: from the training fit's estimate (its
    written values, after the frame-noise refinement if any), with its outlier thresholds for
    the first classification, its residual choice (tracks re-paired over every frame), its
    free parameters and its evaluator (the CasADi functions built once)."""
    t0 = clock()
    rep.start("refit on all frames")
    theta = np.array([res.values[n] for n in THETA_NAMES])
    full = stages.all_frames(prep)
    co_all = replace(co, theta=theta, iterations=0, warnings=())
    md_all = stages.choose_mode(full, co_all, replace(options, residuals=md.mode), md.ev_fine)
    md_all = replace(md_all, warnings=())
    fine_all = stages.fine_fit(full, co_all, md_all, options, rep, warm=fine.thresholds)
    return _finish(full, ini, co_all, md_all, fine_all, options, {}, clock, t0)
