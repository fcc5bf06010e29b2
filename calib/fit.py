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

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.calibration import Calibration
from calib import finish, stages
from calib.data import StreakSet
from calib.fitcore import (
    COARSE_SUBSTEP_S,
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
    _outlier_threshold,
    _rayleigh_sigma,
    _reorient,
    check_fit_inputs,
    classify,
    scale_check,
)
from calib.params import THETA_NAMES
from calib.result import CalibResult

__all__ = [
    "COARSE_SUBSTEP_S",
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
    "_outlier_threshold",
    "_rayleigh_sigma",
    "_reorient",
    "calibrate",
    "check_fit_inputs",
    "classify",
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
    from its estimate (the final stage only; the coarse stages and unobservable parameters
    are those of the training fit): the returned calibration, values and sigma are the
    refit's, the hold-out statistics those of the training fit (``holdout_fit_values``).

    Args:
        streaks: measured streaks, times relative to ``streaks.t0_s``.
        gyro: the session's gyro trace on the absolute IMU clock.
        initial: initial guess (the rig's ``session.yaml``); distortion is kept fixed.
        progress: called with a :class:`Progress` at each stage start and LM iteration.
    """
    t_start = clock()
    res = _fit(streaks, gyro, initial, options, clock, progress, None)
    if not (options.refit_all and options.holdout_fraction > 0 and res.status != "failed"):
        return res
    warm = (np.array([res.values[n] for n in THETA_NAMES]), res.fixed_unobservable)
    full = _fit(
        streaks,
        gyro,
        initial,
        replace(options, holdout_fraction=0.0),
        clock,
        progress,
        warm,
        t_start,
    )
    timings = {**res.timings_s, **{f"refit_{k}": v for k, v in full.timings_s.items()}}
    timings["total"] = clock() - t_start
    return replace(
        full,
        holdout=res.holdout,
        holdout_all=res.holdout_all,
        holdout_fit_values=dict(res.values),
        init_shift_curve=res.init_shift_curve,
        iterations=res.iterations + full.iterations,
        warnings=tuple(dict.fromkeys(res.warnings + full.warnings)),
        timings_s=timings,
    )


def _fit(
    streaks: StreakSet,
    gyro: GyroTrace,
    initial: Calibration,
    options: FitOptions,
    clock: Callable[[], float],
    progress: ProgressFn | None,
    warm: tuple[np.ndarray, tuple[str, ...]] | None,
    t_origin: float | None = None,
) -> CalibResult:
    """One fit (:func:`calibrate`); ``warm``: start the final stage at this theta with these
    parameters held (a refit), skipping the search and the coarse stages."""
    t_start = clock()
    rep = stages.Reporter(progress, clock, t_start if t_origin is None else t_origin)
    timings: dict[str, float] = {}
    prep = stages.prepare(streaks, gyro, initial, options)
    ini = stages.initialise(prep, options, warm, rep)
    timings["init"] = clock() - t_start
    co = stages.coarse_fit(prep, ini, options, warm, rep)
    timings["coarse"] = clock() - t_start - timings["init"]
    md = stages.choose_mode(prep, co, options)
    fine = stages.fine_fit(prep, co, md, options, warm, rep)
    for k, n in enumerate(fine.round_iterations):
        timings[f"fine{k}_iterations"] = n
    timings["fine"] = clock() - t_start - timings["init"] - timings["coarse"]
    gls = finish.frame_noise_fit(prep, co, md, fine) if options.frame_noise else None
    return finish.assemble(prep, ini, co, md, fine, gls, timings, clock, t_start)
