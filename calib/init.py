"""Initialisation: time shift and focal length by coarse-to-fine search on the endpoint cost.

Gauss–Newton on the time shift only converges within roughly the correlation time of the motion
(tens of ms for hand shake), so the shift is first found by a one-dimensional search, the
analogue of Kalibr's cross-correlation of angular speeds: each candidate shift warps measured
streak starts with the gyro and scores the median endpoint error over a subsample of moving
streaks, which compares gyro-predicted with measured streak motion directly (direction
included, not only speed) and ignores outliers. A focal-length scale search follows (focal
length scales every streak's length), then a finer shift search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.data import StreakSet
from calib.params import LAYOUT
from calib.problem import ResidualModel
from calib.solve import Evaluator

#: Streaks scored per candidate.
MAX_INIT_STREAKS = 1500


@dataclass(frozen=True)
class InitResult:
    theta: np.ndarray
    median_error_px: float
    shift_curve: tuple[tuple[float, float], ...]  # (shift s, median error px) of the coarse scan


def _score(model: ResidualModel | Evaluator, theta: np.ndarray, streaks: StreakSet) -> float:
    if isinstance(model, ResidualModel):
        r = model.residual_np(theta, streaks)
    else:
        r = model.residual(theta, streaks)[:, :2]
    return float(np.median(np.linalg.norm(r, axis=1)))


def moving_subsample(
    streaks: StreakSet, n_max: int, seed: int = 0, min_length_px: float = 2.0
) -> np.ndarray:
    """Indices of at most ``n_max`` streaks longer than ``min_length_px`` (all if too few)."""
    idx = np.flatnonzero(streaks.length_px >= min_length_px)
    if idx.size < 20:
        idx = np.arange(len(streaks))
    if idx.size > n_max:
        idx = np.sort(np.random.default_rng(seed).choice(idx, n_max, replace=False))
    return idx


def initialise(
    model: ResidualModel | Evaluator,
    streaks: StreakSet,
    theta0: np.ndarray,
    search_shift: bool,
    search_focal: bool,
    window_s: float = 0.06,
    search: bool = True,
) -> InitResult:
    """Coarse-to-fine search of the time shift (± ``window_s``) and a common focal scale
    (``search=False``: none, only the median error at ``theta0``), scored by the per-streak
    model or an evaluator (the fit's grid: neither the shift nor the focal lengths change its
    orientation integral, so every candidate reuses one)."""
    sub = streaks.subset(moving_subsample(streaks, MAX_INIT_STREAKS))
    theta = np.asarray(theta0, float).copy()
    curve: list[tuple[float, float]] = []

    def scan_shift(center: float, half: float, step: float) -> None:
        cands = center + np.arange(-half, half + step / 2, step)
        scores = []
        for s in cands:
            th = theta.copy()
            th[LAYOUT["timeshift_s"]] = s
            scores.append(_score(model, th, sub))
        if half >= window_s:
            curve.extend(zip(cands.tolist(), scores, strict=True))
        theta[LAYOUT["timeshift_s"]] = float(cands[int(np.argmin(scores))])

    def scan_focal(half: float, step: float) -> None:
        base = theta[LAYOUT["focal"]].copy()
        cands = 1.0 + np.arange(-half, half + step / 2, step)
        scores = []
        for k in cands:
            th = theta.copy()
            th[LAYOUT["focal"]] = base * k
            scores.append(_score(model, th, sub))
        theta[LAYOUT["focal"]] = base * float(cands[int(np.argmin(scores))])

    search_shift, search_focal = search_shift and search, search_focal and search
    if search_shift:
        scan_shift(theta[LAYOUT["timeshift_s"]], window_s, 2e-3)
    if search_focal:
        scan_focal(0.16, 0.01)
    if search_shift:
        scan_shift(theta[LAYOUT["timeshift_s"]], 3e-3, 2e-4)
    if search_focal:
        scan_focal(0.012, 0.002)
    return InitResult(theta, _score(model, theta, sub), tuple(curve))
