"""Calibration options, constants and helpers shared by the fit stages (:mod:`calib.stages`,
:mod:`calib.finish`) and the driver (:mod:`calib.fit`).

The stages themselves are listed in :mod:`calib.fit`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.gyro import GYRO_UPSAMPLE
from calib import uncertainty
from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import (
    DEFAULT_FIT,
    GROUPS,
    THETA_NAMES,
    parse_fit,
)
from calib.problem import ResidualModel
from calib.solve import Evaluator

MIN_STREAKS = 30
MIN_FRAMES = 3
OUTLIER_SIGMAS = 5.0
#: Floor of the outlier threshold (px): detection noise never justifies rejecting less.
MIN_OUTLIER_PX = 0.5
SUBSAMPLE = 2000
#: Robust endpoint sigma (px) above which the data are called contradictory.
MAX_RESIDUAL_SIGMA_PX = 3.0
MIN_INLIER_FRACTION = 0.5
#: Score-test threshold (sigmas) of :func:`scale_check`.
SCALE_Z = 3.0
#: Pseudo-Huber scale of the final stage, in robust sigmas: outliers are gone by then, and a
#: scale near the rejection threshold keeps the IRLS weights of inliers nearly constant, so
#: Gauss–Newton converges in two or three Jacobians.
FINE_DELTA_SIGMAS = 5.0
RESIDUALS = ("auto", "endpoints", "tracks", "both")
#: ``auto`` warns when the tracks number less than this share of the training streaks (most
#: of the streaks then go unused). It still fits the tracks alone: on the ``hard`` preset
#: (about 8 % of the streaks pair up) endpoints, alone or with the tracks, put the gyro bias
#: 4–7e-3 rad/s off at z up to 13, the tracks alone 1.3–1.5e-3 rad/s.
MIN_TRACK_SHARE = 0.25


@dataclass(frozen=True)
class FitOptions:
    fit: str = DEFAULT_FIT
    holdout_fraction: float = 0.2
    shift_window_s: float = 0.06
    max_iter: int = 30
    seed: int = 0
    #: Cubic-spline upsampling of the gyro before linear interpolation: the blur model's
    #: (:data:`blurtrack.geometry.gyro.GYRO_UPSAMPLE`); another value fits a model that prediction
    #: and
    #: synthesis do not use, so it is for experiments only.
    gyro_upsample: int = GYRO_UPSAMPLE
    #: Centre-line residuals (:mod:`calib.centreline`) in the final stage; the streaks must
    #: carry centre points (``streaks_from_table(..., centre_k=CENTRE_POINTS)``).
    centreline: bool = False
    #: Generalised-least-squares refinement under the frame-correlated gyro-noise model
    #: (:mod:`calib.framenoise`) after the robust fit.
    frame_noise: bool = False
    #: What the final stage fits: ``endpoints`` (each streak's end predicted from its start),
    #: ``tracks`` (each dot's time midpoint carried to the next frame, :mod:`calib.tracks`;
    #: insensitive to biased streak ends), ``both``, or ``auto``: tracks when the streaks
    #: carry midpoints and at least 30 tracks pair up, else endpoints (a warning says why; it
    #: also warns when tracks are under :data:`MIN_TRACK_SHARE` of the streaks). The result's
    #: ``residuals`` names the choice. Initialisation always uses endpoints.
    residuals: str = "auto"
    #: After the hold-out evaluation, refit on every frame (what is written); see
    #: :func:`calibrate`.
    refit_all: bool = True

    def __post_init__(self) -> None:
        if self.residuals not in RESIDUALS:
            raise CalibError(
                f"residuals must be one of {', '.join(RESIDUALS)}, got {self.residuals!r}"
            )
        if self.residuals in ("tracks", "both") and (self.centreline or self.frame_noise):
            raise CalibError(
                "centre-line residuals and the frame-noise refinement work on "
                "endpoint residuals only (--residuals endpoints)"
            )


def rayleigh_sigma(rho: np.ndarray) -> float:
    """Per-coordinate sigma from the median 2-D error (Rayleigh median = 1.1774 sigma)."""
    return float(np.median(rho) / 1.1774) if rho.size else 0.0


def outlier_threshold(rho_inliers: np.ndarray) -> float:
    """Rejection threshold (px) from the current inliers' errors."""
    return max(OUTLIER_SIGMAS * rayleigh_sigma(rho_inliers), MIN_OUTLIER_PX)


def classify(
    model: ResidualModel, theta: np.ndarray, streaks: StreakSet, threshold_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Endpoint errors ``(N,)``, outlier mask and wrongly-oriented mask at ``theta``."""
    rho = np.linalg.norm(model.residual_np(theta, streaks), axis=1)
    out = rho > threshold_px
    flipped, _ = _fit_reversed(model, theta, streaks, out, threshold_px)
    return rho, out, flipped


def _fit_reversed(
    model: ResidualModel,
    theta: np.ndarray,
    streaks: StreakSet,
    out: np.ndarray,
    threshold_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Which of the outliers ``out`` fit within ``threshold_px`` with start and end swapped
    (mask over all streaks), and the outliers' endpoint errors reversed ``(out.sum(),)``."""
    fits = np.zeros_like(out)
    rf = np.zeros(0)
    if np.any(out):
        rf = np.linalg.norm(model.residual_np(theta, streaks.subset(out).flipped()), axis=1)
        fits[np.flatnonzero(out)] = rf <= threshold_px
    return fits, rf


def reorient(
    model: ResidualModel,
    theta: np.ndarray,
    streaks: StreakSet,
    threshold_px: float,
    rho: np.ndarray | None = None,
) -> tuple[StreakSet, np.ndarray, np.ndarray]:
    """Swap start and end of the streaks that only fit reversed (orientation resolved wrongly
    by detection). Returns the corrected set, its endpoint errors and the swapped mask.
    ``rho``: the endpoint errors at ``theta`` when already known (only the outliers are then
    evaluated again, reversed)."""
    if rho is None:
        rho = np.linalg.norm(model.residual_np(theta, streaks), axis=1)
    out = rho > threshold_px
    flip, rf = _fit_reversed(model, theta, streaks, out, threshold_px)
    if np.any(flip):
        streaks = streaks.reoriented(flip)
        rho = rho.copy()
        rho[flip] = rf[flip[out]]
    return streaks, rho, flip


def scale_check(
    ev: Evaluator,
    theta: np.ndarray,
    streaks: StreakSet,
    weights: np.ndarray,
    free: tuple[int, ...],
) -> list[str]:
    """Warn when the data ask for a gyro scale / cross-axis error that is not being fitted.

    One Gauss–Newton step from the optimum with the scale entries freed (the score test):
    an entry that would move by more than :data:`SCALE_Z` of its own (cluster-robust) sigma
    means the fixed scale is wrong and the focal lengths' sigma are optimistic.
    """
    extra = tuple(i for i in GROUPS["scale"] if i not in free)
    if not extra:
        return []
    full = tuple(sorted(free + extra))
    r, J = ev.evaluate(theta, streaks, full)
    A = uncertainty.information(J, weights, full)
    g = np.einsum("n,nki,nk->i", weights, J[:, :, list(full)], r)
    try:
        step = -np.linalg.solve(A, g)
    except np.linalg.LinAlgError:
        return []
    # Sigma under the alternative: residuals after the (linearised) step.
    r_alt = r + np.einsum("nki,i->nk", J[:, :, list(full)], step)
    unc = uncertainty.estimate(J, r_alt, weights, streaks.frame, full)
    z = {THETA_NAMES[i]: step[k] / unc.sigma[k] for k, i in enumerate(full) if i in extra}
    big = {k: v for k, v in z.items() if abs(v) > SCALE_Z}
    if not big:
        return []
    worst = max(big, key=lambda k: abs(big[k]))
    return [
        f"the gyro shows a scale/cross-axis error that is not fitted ({worst} "
        f"{step[full.index(THETA_NAMES.index(worst))]:+.2e}, {abs(big[worst]):.0f} sigma): "
        f"focal lengths and rotation absorb it and their sigma are optimistic; "
        f"refit with --fit ...,scale"
    ]


@dataclass(frozen=True)
class Progress:
    """One progress report of :func:`calibrate`: the stage, its LM iteration (0: the stage
    starts), the cost after it and the seconds since the fit started."""

    stage: str
    iteration: int
    cost: float
    elapsed_s: float


ProgressFn = Callable[[Progress], None]


def check_fit_inputs(streaks: StreakSet, options: FitOptions) -> tuple[int, ...]:
    """Refuse unusable input before any work (raises :class:`CalibError`); returns the parsed
    ``--fit`` groups. ``calibrate`` calls it first; the CLI calls it before the axis search."""
    free = parse_fit(options.fit)
    if options.centreline and streaks.centre is None:
        raise CalibError("centre-line residuals asked for, but the streaks carry no centre lines")
    if len(streaks) < MIN_STREAKS or streaks.n_frames < MIN_FRAMES:
        raise CalibError(
            f"too few streaks to calibrate: {len(streaks)} in {streaks.n_frames} "
            f"frame(s); need at least {MIN_STREAKS} in {MIN_FRAMES} frames"
        )
    return free
