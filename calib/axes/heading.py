"""Camera–IMU axes of a translating camera: the gyro's rotation leaves a common heading.

:mod:`calib.axes.search` scores each candidate by the inter-frame rotations the images measure on
their own, which assumes a far scene (or, :mod:`calib.axes.translation`, a zoom about the
principal point). A phone on a car's dashboard breaks both: near buildings and overhead signs
slide metres-scale parallax past far towers, and a rotation fitted to such tracks mixes
parallax into rotation (the shared 800×600 drive: the best candidate leaves 1.29 px of a
3.20 px median rotation, refused).

Here the gyro, not the images, gives each candidate's rotation, and the images only have to
be consistent with it. For candidate ``P`` at time shift ``s``, each track's first bearing is
carried by the predicted rotation of its frame pair, ``â = R_pred · a``
(``R_pred = (P · M_imu · Pᵀ)ᵀ``, as in :mod:`calib.axes.search`); what is left between ``â`` and the
second bearing ``b`` must be translation: ``b`` lies on the great circle through ``â`` and the
direction of travel ``h`` (the epipolar constraint with known rotation, ``h · (â × b) = 0``).
A camera rigid on a vehicle travels along one direction in its own frame (the vehicle's
heading; no side slip), so one ``h`` serves every frame pair: 2 parameters for the whole
recording, fitted per candidate by iteratively reweighted least squares (the smallest
eigenvector of the weighted ``Σ n nᵀ``, ``n = â × b``, tracks beyond three times the median
residual left out). A candidate's score is the median distance of ``b`` from its epipolar
circle, in pixels (angle · fx).

Why one heading and not one per pair: with a free direction per pair a wrong rotation's
nearly uniform error flow is absorbed by a sideways translation (the ambiguity described in
:mod:`calib.axes.translation`); one direction for all pairs cannot absorb errors that differ
from pair to pair, and with no translation at all (a far scene) any ``h`` fits the correct
candidate. Tracks that move with the camera (a dashboard: still in the image while the gyro
turns) or on other vehicles disagree with the winner and are counted in :class:`HeadingSearch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from calib.axes.search import (
    AxisSearch,
    covered_pairs,
    gyro_rotations,
    proper_axis_permutations,
    ranked,
    scan_candidates,
)

#: Most tracks per frame pair that score a candidate (evenly taken; the score is a median),
#: and most in all (long recordings: fewer per pair, at least :data:`MIN_TRACKS_PER_PAIR`).
MAX_TRACKS_PER_PAIR = 80
MAX_TRACKS = 4000
MIN_TRACKS_PER_PAIR = 16
#: Tracks per frame pair of the coarse scan of all 24 candidates over the shift window;
#: every candidate is then scored again at its best shift with all the tracks above.
COARSE_TRACKS_PER_PAIR = 16
#: Reweighting rounds of the heading fit.
HEADING_ROUNDS = 4
#: Tracks farther than this many times the median residual from their epipolar circle are
#: left out of the next round (a consensus, not a least-squares compromise).
OUTLIER_FACTOR = 3.0
#: Floor of that gate (rad at fx = 1; times fx it is px): the gate never drops below
#: ``GATE_FLOOR_PX / fx``.
GATE_FLOOR_PX = 0.3
#: A track is "still" (moves with the camera: a dashboard, a reflection of the cabin) when it
#: moves less than this in the image (px) while the winner's rotation moves it by more than
#: :data:`STILL_ROTATION_PX`.
STILL_PX = 0.5
STILL_ROTATION_PX = 1.5


@dataclass(frozen=True)
class HeadingSearch:
    """The axis search of the common-heading model and what its winner left out.

    Attributes:
        search: the 24 candidates ranked (scores: median epipolar distance, px).
        heading_cam: ``(3,)`` unit direction of travel in the camera frame (sign undefined:
            forward and backward travel give the same epipolar circles).
        n_tracks: tracks scored; ``n_left_out``: tracks beyond the winner's gate;
            ``n_still``: of those, tracks that stay still while the winner's rotation moves
            them (parts rigid with the camera).
        still_box_px: ``(x0, y0, x1, y1)`` of the still tracks (None without any).
    """

    search: AxisSearch
    heading_cam: np.ndarray
    n_tracks: int
    n_left_out: int
    n_still: int
    still_box_px: tuple[float, float, float, float] | None

    def to_dict(self) -> dict:
        return {
            **self.search.to_dict(),
            "model": "common heading",
            "heading_cam": [float(v) for v in self.heading_cam],
            "tracks_scored": self.n_tracks,
            "tracks_left_out": self.n_left_out,
            "tracks_still_while_turning": self.n_still,
            "still_box_px": None if self.still_box_px is None else list(self.still_box_px),
        }


def epipolar_distance(a_rot: np.ndarray, b: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Sine of the angle (≈ the angle in rad, the px / fx) of unit bearings ``b (..., N, 3)``
    from the great circles through the derotated first bearings ``a_rot (..., N, 3)`` and
    ``heading (..., 3)``.

    >>> a = np.array([[0.0, 0.0, 1.0]]); b = np.array([[0.0, 0.6, 0.8]])
    >>> float(epipolar_distance(a, b, np.array([0.0, 1.0, 0.0]))[0])  # on the circle
    0.0
    """
    h = np.asarray(heading, float)[..., None, :]
    m = np.cross(h, a_rot)
    norm = np.maximum(np.linalg.norm(m, axis=-1), 1e-9)
    return np.abs(np.einsum("...i,...i->...", m, b)) / norm


def fit_heading(
    a_rot: np.ndarray, b: np.ndarray, gate_floor: float, rounds: int = HEADING_ROUNDS
) -> tuple[np.ndarray, np.ndarray]:
    """Common heading of candidates' derotated bearings ``a_rot (C, N, 3)`` against ``b
    (N, 3)``: ``(C, 3)`` unit headings and ``(C, N)`` epipolar distances (rad).

    Each round solves ``min Σ wᵢ (h · nᵢ)² / |h × âᵢ|²`` (``nᵢ = âᵢ × bᵢ``; the denominator
    from the previous round makes the algebraic residual the epipolar distance), with
    ``wᵢ = 0`` beyond :data:`OUTLIER_FACTOR` times the median distance (at least
    ``gate_floor``)."""
    n = np.cross(a_rot, b[None])
    w = np.ones(a_rot.shape[:2])
    h = np.zeros((a_rot.shape[0], 3))
    r = np.zeros(a_rot.shape[:2])
    for k in range(rounds + 1):
        M = np.einsum("cn,cni,cnj->cij", w, n, n)
        h = np.linalg.eigh(M)[1][:, :, 0]
        r = epipolar_distance(a_rot, b[None], h)
        if k == rounds:
            break
        gate = np.maximum(OUTLIER_FACTOR * np.median(r, axis=1), gate_floor)
        sin2 = np.maximum(np.linalg.norm(np.cross(h[:, None], a_rot), axis=-1), 0.05) ** 2
        w = (r <= gate[:, None]) / sin2
    return h, r


def _subsample(pair: np.ndarray, per_pair: int) -> np.ndarray:
    """Indices of at most ``per_pair`` tracks of each pair, evenly spaced in their order."""
    keep = []
    for f in np.unique(pair):
        sel = np.flatnonzero(pair == f)
        if sel.size > per_pair:
            sel = sel[np.linspace(0, sel.size - 1, per_pair).round().astype(np.int64)]
        keep.append(sel)
    return np.concatenate(keep) if keep else np.zeros(0, np.int64)


def search_axes_heading(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    pair: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    camera: Camera,
    gyro: GyroTrace,
    shift0_s: float,
    window_s: float,
    motion_px: float,
    source: str = "feature tracks, common heading",
) -> HeadingSearch:
    """Score the 24 axis candidates with the common-heading model (module docstring).

    Args:
        pts_a, pts_b: ``(N, 2)`` tracked pixels in frames ``pair`` and ``pair + 1``.
        pair: ``(N,)`` earlier frame of each track; ``frame_t_s``, ``exposure_s`` per frame
            (s, the gyro's origin).
        gyro: the IMU-clock trace, upsampled; ``shift0_s ± window_s`` searched as in
            :func:`calib.axes.search.search_axes`.
        motion_px: the images' median inter-frame rotation (px), reported with the search.
    """
    pair = np.asarray(pair, np.int64)
    n_pairs = max(1, np.unique(pair).size)
    per = max(MIN_TRACKS_PER_PAIR, min(MAX_TRACKS_PER_PAIR, MAX_TRACKS // n_pairs))
    sel = _subsample(pair, per)
    pa, pb, fa = np.asarray(pts_a, float)[sel], np.asarray(pts_b, float)[sel], pair[sel]
    pairs, idx = np.unique(fa, return_inverse=True)
    H, fx = camera.height, camera.intrinsics[0]
    ta = np.array([pa[idx == k, 1].mean() for k in range(pairs.size)])
    tb = np.array([pb[idx == k, 1].mean() for k in range(pairs.size)])
    ta = frame_t_s[pairs] + camera.readout_s * ta / H + exposure_s[pairs] / 2
    tb = frame_t_s[pairs + 1] + camera.readout_s * tb / H + exposure_s[pairs + 1] / 2
    ok = covered_pairs(gyro, ta, tb, shift0_s, window_s)
    use = ok[idx]
    pa, pb, idx = pa[use], pb[use], np.searchsorted(np.flatnonzero(ok), idx[use])
    ta, tb = ta[ok], tb[ok]
    a = camera.unproject(pa)
    b = camera.unproject(pb)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    P = proper_axis_permutations()

    def derotated(shift: float, which: np.ndarray, sub: np.ndarray) -> np.ndarray:
        """First bearings of tracks ``sub`` carried by candidates ``which``: ``(C, n, 3)``."""
        M = gyro_rotations(gyro, ta, tb, shift)  # (K, 3, 3) R_imu(a)ᵀ R_imu(b)
        Rc = np.einsum("cij,kjl,cml->ckim", P[which], M, P[which])  # P M Pᵀ per candidate
        # bearing_b = Rcᵀ bearing_a for a static far point
        return np.einsum("cnji,nj->cni", Rc[:, idx[sub]], a[sub])

    def score(shift: float, which: np.ndarray, sub: np.ndarray) -> np.ndarray:
        _, r = fit_heading(derotated(shift, which, sub), b[sub], GATE_FLOOR_PX / fx)
        return np.median(r, axis=1) * fx

    # coarse and fine scans on a few tracks per pair; every candidate then scored with all
    few = _subsample(idx, COARSE_TRACKS_PER_PAIR)
    shifts, _ = scan_candidates(lambda s, w: score(s, w, few), shift0_s, window_s)
    every = np.arange(len(a))
    scores = np.array([score(float(shifts[c]), np.array([c]), every)[0] for c in range(len(P))])
    search = ranked(shifts, scores, motion_px, int(pairs[ok].size), source)
    win = np.array([int(np.argmin(scores))])
    a_rot = derotated(float(shifts[win[0]]), win, every)
    h, r = fit_heading(a_rot, b, GATE_FLOOR_PX / fx)
    gate = max(OUTLIER_FACTOR * float(np.median(r[0])), GATE_FLOOR_PX / fx)
    out = r[0] > gate
    moved_img = np.linalg.norm(pb - pa, axis=1)
    moved_rot = np.linalg.norm(a_rot[0] - a, axis=1) * fx
    still = out & (moved_img < STILL_PX) & (moved_rot > STILL_ROTATION_PX)
    box = None
    if still.any():
        q = pa[still]
        box = (
            float(q[:, 0].min()),
            float(q[:, 1].min()),
            float(q[:, 0].max()),
            float(q[:, 1].max()),
        )
    return HeadingSearch(
        search, h[0], len(a), int(np.count_nonzero(out)), int(np.count_nonzero(still)), box
    )
