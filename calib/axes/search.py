"""Camera–IMU axis discovery: which of the 24 proper signed axis permutations the data choose.

An importer or a rig rarely knows how its gyro's axes sit in the camera frame, and a wrong
guess (a swapped pair, a flipped sign) predicts blur backwards. The images decide: between two
frames ``a`` and ``b`` the static scene turns by a rotation that the images measure on their
own (feature tracks or laser-dot midpoints, :func:`fit_rotation` on bearing vectors
``K⁻¹ x̃``, no gyro used), and that the gyro predicts for every candidate ``P``:

    bearing_b = R_img · bearing_a,   R_img = R_c(t_a)ᵀ R_c(t_b) ... transposed:
    R_img = (P · M_imu · Pᵀ)ᵀ,       M_imu = R_imu(t_a + shift)ᵀ R_imu(t_b + shift)

with ``M_imu`` the gyro's integrated relative rotation (the blur model's exact integration,
:func:`blurtrack.geometry.kernels.relative_rotation`) on the IMU clock, ``t_imu = t_cam +
shift`` (DESIGN's sign). Times are the pair's rows' exposure midpoints (rolling shutter:
``t + readout · ȳ / H + exposure / 2``). A candidate's score is the median over frame pairs of
the angle between measured and predicted rotation, in pixels (angle · fx), minimised over a
coarse-to-fine time-shift search: a wrong mapping cannot be rescued by another offset.

:func:`search_axes` scores all 24, :func:`check_axes` refuses (:class:`AxisSearchError`) when
the images hardly rotate, when no candidate explains them, or when the winner is not clearly
better than the runner-up.

The image rotations (:class:`~calib.axes.rotations.ImageRotations`) are measured by
:mod:`calib.axes.rotations`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np

from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.geometry.kernels import n_substeps, relative_rotation
from blurtrack.geometry.rotation import so3_log
from calib.axes.rotations import (
    MIN_PAIRS,
    ImageRotations,
)
from calib.errors import AxisSearchError, CalibError

#: Median measured inter-frame rotation (px at fx) below which the images hardly rotate.
MIN_MOTION_PX = 1.0


#: Runner-up score / winner score below which the winner is not clearly separated.
MIN_MARGIN = 2.0


#: Winner score / median motion above which no candidate explains the images.
MAX_WINNER_FRACTION = 0.4


#: Range of the common gain between measured and gyro rotations that the search allows for
#: (focal length or gyro scale off by up to this much).
GAIN_RANGE = (0.67, 1.5)


#: Coarse and fine shift-search steps (s).
COARSE_STEP_S = 2e-3


FINE_STEP_S = 2e-4


def proper_axis_permutations() -> np.ndarray:
    """The 24 signed permutation matrices with determinant +1, ``(24, 3, 3)``.

    >>> P = proper_axis_permutations()
    >>> P.shape, bool(np.allclose(np.linalg.det(P), 1.0))
    ((24, 3, 3), True)
    """
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    return np.stack(out)


def nearest_axis_permutation(R: np.ndarray) -> int:
    """Index into :func:`proper_axis_permutations` of the candidate closest to ``R`` (3, 3)."""
    P = proper_axis_permutations()
    return int(np.argmax(np.einsum("kij,ij->k", P, np.asarray(R, float))))


@dataclass(frozen=True)
class AxisCandidate:
    """One signed axis permutation with its best time shift and score (px)."""

    R_cam_imu: tuple[tuple[float, float, float], ...]
    timeshift_s: float
    score_px: float

    def to_dict(self) -> dict:
        return {
            "R_cam_imu": [list(r) for r in self.R_cam_imu],
            "timeshift_s": self.timeshift_s,
            "score_px": self.score_px,
        }


@dataclass(frozen=True)
class AxisSearch:
    """Result of :func:`search_axes`: every candidate, best first.

    ``margin`` is the runner-up's score over the winner's; ``motion_px`` the median measured
    inter-frame rotation (px at fx); ``n_pairs`` the frame pairs scored.
    """

    candidates: tuple[AxisCandidate, ...]
    motion_px: float
    n_pairs: int
    source: str
    #: How the axes were decided when more than one motion model was consulted
    #: (:func:`calib.natural.pipeline.discover_axes`): the model used and each model's figures.
    decision: dict | None = None

    def __post_init__(self) -> None:
        if len(self.candidates) != 24:
            raise CalibError("an axis search scores all 24 proper axis permutations")
        s = [c.score_px for c in self.candidates]
        if s != sorted(s):
            raise CalibError("axis candidates must be sorted best first")

    @property
    def winner(self) -> AxisCandidate:
        return self.candidates[0]

    @property
    def runner_up(self) -> AxisCandidate:
        return self.candidates[1]

    @property
    def margin(self) -> float:
        return self.runner_up.score_px / max(self.winner.score_px, 1e-12)

    @property
    def R_cam_imu(self) -> np.ndarray:
        return np.array(self.winner.R_cam_imu)

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "n_pairs": self.n_pairs,
            "motion_px": self.motion_px,
            "margin": self.margin,
            "winner": self.winner.to_dict(),
            "candidates": [c.to_dict() for c in self.candidates],
            **({"decision": self.decision} if self.decision is not None else {}),
        }


def gyro_rotations(
    gyro: GyroTrace, t_a_s: np.ndarray, t_b_s: np.ndarray, shift_s: float
) -> np.ndarray:
    """``(K, 3, 3)`` relative IMU rotations ``R_imu(t_a+shift)ᵀ R_imu(t_b+shift)``."""
    n_sub = n_substeps(float(np.max(np.abs(t_b_s - t_a_s))))

    def omega(t: np.ndarray) -> tuple:
        return gyro.omega_components(t + shift_s)

    R = relative_rotation(t_a_s, t_b_s, omega, n_sub)
    return np.stack(R, axis=-1).reshape(-1, 3, 3)


def _misfit(rv_img: np.ndarray, rv_gyro: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``(C,)`` median misfit (rad) of measured rotation vectors ``(K, 3)`` against each
    candidate's prediction ``g · P r_gyro`` with its best common gain ``g`` in
    :data:`GAIN_RANGE` (a focal-length or gyro-scale error scales every rotation alike)."""
    pred = np.einsum("cij,kj->cki", P, rv_gyro)
    num = np.einsum("cki,ki->c", pred, rv_img)
    den = np.einsum("cki,cki->c", pred, pred)
    gain = np.clip(num / np.maximum(den, 1e-300), *GAIN_RANGE)
    return np.median(np.linalg.norm(rv_img[None] - gain[:, None, None] * pred, axis=2), axis=1)


def search_axes(
    rots: ImageRotations,
    gyro: GyroTrace,
    fx: float,
    shift0_s: float,
    window_s: float,
    source: str,
) -> AxisSearch:
    """Score all 24 proper axis permutations (see the module docstring).

    ``gyro`` is on the IMU clock with the same origin as ``rots``' times; ``shift0_s ±
    window_s`` is searched. Frame pairs the gyro does not cover over the whole window are left
    out; :class:`AxisSearchError` when fewer than :data:`MIN_PAIRS` remain.
    """
    g = gyro.upsampled(GYRO_UPSAMPLE)
    ok = covered_pairs(g, rots.t_a_s, rots.t_b_s, shift0_s, window_s)
    ta, tb, Ri = rots.t_a_s[ok], rots.t_b_s[ok], rots.R_img[ok]
    P = proper_axis_permutations()

    rv_img = so3_log(Ri)

    def score(shift: float, which: np.ndarray) -> np.ndarray:
        # b = R_img a with R_img = (P M Pᵀ)ᵀ: the measured rotation vector is P · log(Mᵀ).
        rv_gyro = so3_log(np.swapaxes(gyro_rotations(g, ta, tb, shift), 1, 2))
        return _misfit(rv_img, rv_gyro, P[which]) * fx

    shifts, scores = scan_candidates(score, shift0_s, window_s)
    ang = np.linalg.norm(rv_img, axis=1)
    n_tr = int(np.count_nonzero(np.asarray(rots.translating, bool)[ok]))
    if n_tr:
        source += f" ({n_tr} of {int(np.count_nonzero(ok))} pairs with translation)"
    return ranked(shifts, scores, float(np.median(ang) * fx), int(np.count_nonzero(ok)), source)


def covered_pairs(
    gyro: GyroTrace, t_a_s: np.ndarray, t_b_s: np.ndarray, shift0_s: float, window_s: float
) -> np.ndarray:
    """``(K,)`` the frame pairs (camera times ``t_a_s``, ``t_b_s``) whose interval the gyro
    covers for every shift of ``shift0_s ± window_s``; :class:`AxisSearchError` when fewer
    than :data:`MIN_PAIRS` are."""
    lo = np.minimum(t_a_s, t_b_s) + shift0_s - window_s
    hi = np.maximum(t_a_s, t_b_s) + shift0_s + window_s
    ok = np.array([gyro.covers(float(a), float(b)) for a, b in zip(lo, hi, strict=True)])
    if np.count_nonzero(ok) < MIN_PAIRS:
        raise AxisSearchError(
            f"the gyro does not cover the frames: {np.count_nonzero(ok)} of {len(ok)} "
            f"frame pairs (± {window_s * 1e3:.0f} ms shift search) lie inside its samples; "
            f"need {MIN_PAIRS}"
        )
    return ok


def scan_candidates(
    score: Callable[[float, np.ndarray], np.ndarray], shift0_s: float, window_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Best time shift and score ``(24,)`` of every candidate.

    ``score(shift_s, which)`` gives the scores (px) of candidates ``which`` (indices into
    :func:`proper_axis_permutations`) at one shift. A coarse scan of ``shift0 ± window`` in
    :data:`COARSE_STEP_S` steps for all, then a :data:`FINE_STEP_S` scan around the three
    leaders' best.
    """
    allc = np.arange(24)
    coarse = shift0_s + np.arange(-window_s, window_s + COARSE_STEP_S / 2, COARSE_STEP_S)
    sc = np.stack([score(float(s), allc) for s in coarse], axis=1)
    best_shift = coarse[np.argmin(sc, axis=1)]
    best_score = sc.min(axis=1)
    for c in allc[np.argsort(best_score)[:3]]:
        fine = best_shift[c] + np.arange(-COARSE_STEP_S, COARSE_STEP_S + 1e-9, FINE_STEP_S)
        fs = np.array([score(float(s), np.array([c]))[0] for s in fine])
        best_shift[c], best_score[c] = fine[np.argmin(fs)], fs.min()
    return best_shift, best_score


def ranked(
    shifts: np.ndarray, scores: np.ndarray, motion_px: float, n_pairs: int, source: str
) -> AxisSearch:
    """The :class:`AxisSearch` of per-candidate shifts and scores ``(24,)``, best first."""
    P = proper_axis_permutations()
    order = np.argsort(scores, kind="stable")
    return AxisSearch(
        candidates=tuple(
            AxisCandidate(
                cast(
                    "tuple[tuple[float, float, float], ...]",
                    tuple(tuple(float(x) for x in r) for r in P[c]),
                ),
                float(shifts[c]),
                float(scores[c]),
            )
            for c in order
        ),
        motion_px=motion_px,
        n_pairs=n_pairs,
        source=source,
    )


def check_axes(search: AxisSearch) -> None:
    """Raise :class:`AxisSearchError` unless the search decided the axes clearly."""
    w = search.winner
    if search.motion_px < MIN_MOTION_PX:
        # Feature tracks measure the images' rotation; laser midpoints, the gyro's carrying
        # of the dots (:func:`calib.axes.laser.search_axes_laser`): a gyro of zeros shows there.
        laser = search.source.startswith("laser")
        moved = "the gyro carries the dots" if laser else "the images turn"
        why = " (a gyro stream of zeros, or a camera at rest)" if laser else ""
        raise AxisSearchError(
            f"no rotation to speak of: {moved} by a median {search.motion_px:.2f} px between "
            f"frames (need {MIN_MOTION_PX:g}){why}; the camera–IMU axes cannot be decided"
        )
    if w.score_px > MAX_WINNER_FRACTION * search.motion_px:
        raise AxisSearchError(
            f"no camera–IMU axis mapping explains the images: the best leaves "
            f"{w.score_px:.2f} px of a {search.motion_px:.2f} px median inter-frame rotation "
            f"(wrong gyro log, or a moving scene?)"
        )
    if search.margin < MIN_MARGIN:
        raise AxisSearchError(
            f"the camera–IMU axis mapping is ambiguous: the best two score {w.score_px:.2f} "
            f"and {search.runner_up.score_px:.2f} px (margin {search.margin:.2f}, need "
            f"{MIN_MARGIN:g}); record with rotation about all three axes"
        )
