"""Rotations between frame pairs measured from the images alone (no gyro).

Between two frames ``a`` and ``b`` a static scene seen by a turning camera moves by one rotation
of the bearing vectors ``K⁻¹ x̃``: ``bearing_b = R_img · bearing_a``. :func:`fit_rotation` finds
it from matched bearings (RANSAC over minimal Kabsch fits, refined on the inliers); one frame
pair is measured at a time (:func:`pair_rotation`, at the rows' exposure midpoints: rolling
shutter ``t + readout · ȳ / H + exposure / 2``) and the pairs are gathered into
:class:`ImageRotations` (:func:`collect_rotations`). :func:`rotations_from_pairs` measures every
pair of a finished track set; a natural calibration measures each pair on the tracking thread
that has just tracked it (:mod:`calib.natural.pairs`). A pair's rotation depends only on its
own matches (its RANSAC seed is its frame index), so both give the same values. The axis search
(:mod:`calib.axes.search`) compares these with the gyro's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.camera import Camera
from calib.errors import AxisSearchError, CalibError

#: Fewest frame pairs with a measured rotation.
MIN_PAIRS = 3


#: Fewest point pairs behind one measured rotation.
MIN_POINTS = 8


#: A frame pair's rotation fit: ``(a, b, threshold_rad, seed) -> (R, inliers, translating)``.
PairFit = Callable[[np.ndarray, np.ndarray, float, int], "tuple[np.ndarray, np.ndarray, bool]"]


def fit_rotation(
    a: np.ndarray,
    b: np.ndarray,
    threshold_rad: float,
    iterations: int = 64,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Robust rotation ``R`` with ``b ≈ R a`` from unit bearings ``a, b (N, 3)``.

    RANSAC over two-point samples (Kabsch on each), then Kabsch on the inliers of the best
    sample (angular error below ``threshold_rad``) and once more on the refit's inliers.
    Returns ``R (3, 3)`` and the inlier mask ``(N,)``.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    n = a.shape[0]
    if n < 2:
        raise AxisSearchError(f"a rotation needs at least 2 point pairs, got {n}")
    rng = np.random.default_rng(seed)

    def inliers(R: np.ndarray) -> np.ndarray:
        return np.linalg.norm(a @ R.T - b, axis=1) < threshold_rad

    # all samples' Kabsch fits and inlier sets at once (the same per-matrix BLAS and LAPACK
    # calls as one sample at a time, in one call each: 5x faster on 300 frame pairs)
    best = np.ones(n, dtype=bool)
    if iterations > 0:
        pick = np.array([rng.choice(n, 2, replace=False) for _ in range(iterations)])
        inl_all = _inliers_many(a, b, _kabsch_many(a[pick], b[pick]), threshold_rad)
        counts = np.count_nonzero(inl_all, axis=1)
        k = int(np.argmax(counts))  # the first sample with the most inliers
        if counts[k] >= 2:
            best = inl_all[k]
    R = kabsch(a[best], b[best])
    inl = inliers(R)
    if np.count_nonzero(inl) >= 2:
        R = kabsch(a[inl], b[inl])
        inl = inliers(R)
    return R, inl


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-squares rotation ``R`` (det +1) minimising ``Σ |R aᵢ − bᵢ|²`` for ``(N, 3)``."""
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    return U @ D @ Vt


def _kabsch_many(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`kabsch` of each of ``a, b (K, M, 3)``: ``(K, 3, 3)``, the same values."""
    U, _, Vt = np.linalg.svd(np.swapaxes(b, 1, 2) @ a)
    sign = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros((len(a), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(sign == 0, 1.0, sign)
    return U @ D @ Vt


def _inliers_many(a: np.ndarray, b: np.ndarray, R: np.ndarray, threshold_rad: float) -> np.ndarray:
    """``(K, N)`` inlier masks of rotations ``R (K, 3, 3)`` (as :func:`fit_rotation`'s gate)."""
    return np.linalg.norm(a[None] @ np.swapaxes(R, 1, 2) - b[None], axis=2) < threshold_rad


@dataclass(frozen=True)
class ImageRotations:
    """Inter-frame rotations measured by the images alone.

    Attributes:
        t_a_s, t_b_s: ``(K,)`` camera times of the two frames' measured points (exposure
            midpoints of their mean rows), same origin as the gyro trace passed to the search.
        R_img: ``(K, 3, 3)`` rotations with ``bearing_b ≈ R_img · bearing_a``.
        n_points: ``(K,)`` inlier point pairs behind each rotation.
        frame_a: ``(K,)`` index of the earlier frame.
        translating: ``(K,)`` whether the rotation was measured with the camera's translation
            as a nuisance (:mod:`calib.axes.translation`); all false when ``None``.
    """

    t_a_s: np.ndarray
    t_b_s: np.ndarray
    R_img: np.ndarray
    n_points: np.ndarray
    frame_a: np.ndarray
    translating: np.ndarray | None = None

    def __post_init__(self) -> None:
        k = np.asarray(self.t_a_s).size
        tr = np.zeros(k, bool) if self.translating is None else np.asarray(self.translating)
        if tr.shape != (k,):
            raise CalibError(f"image rotations: translating must have shape {(k,)}")
        object.__setattr__(self, "translating", tr.astype(bool))
        for name, shape in (
            ("t_a_s", (k,)),
            ("t_b_s", (k,)),
            ("R_img", (k, 3, 3)),
            ("n_points", (k,)),
            ("frame_a", (k,)),
        ):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != shape or not np.all(np.isfinite(v)):
                raise CalibError(f"image rotations: {name} must be finite with shape {shape}")
            object.__setattr__(self, name, v)

    def __len__(self) -> int:
        return int(self.t_a_s.size)


def rotations_from_pairs(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    pair: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    camera: Camera,
    threshold_px: float = 2.0,
    pair_fit: PairFit | None = None,
) -> ImageRotations:
    """Per-frame-pair rotations from matched points.

    Args:
        pts_a, pts_b: ``(N, 2)`` pixels of the same scene points in frames ``pair`` and the
            next one.
        pair: ``(N,)`` index ``a`` of the earlier frame of each match; the later frame is
            ``a + 1``; ``frame_t_s``/``exposure_s`` are indexed by frame.
        threshold_px: RANSAC inlier gate (converted to an angle with fx).
        pair_fit: ``(a, b, threshold_rad, seed) -> (R, inliers, translating)`` on a pair's
            unit bearings; default :func:`fit_rotation` (pure rotation).
    """
    # each pair's matches in their order, without a mask over all matches per pair
    order = np.argsort(pair, kind="stable")
    firsts, starts = np.unique(pair[order], return_index=True)
    sels = np.split(order, starts[1:]) if firsts.size else []
    return collect_rotations(
        [
            pair_rotation(
                pts_a[s], pts_b[s], int(f), frame_t_s, exposure_s, camera, threshold_px, pair_fit
            )
            for f, s in zip(firsts, sels, strict=True)
        ]
    )


#: One frame pair's measured rotation: times of its two frames' points, ``R (3, 3)``, inlier
#: count, earlier frame, translating (:func:`pair_rotation`).
PairRotation = tuple[float, float, np.ndarray, int, int, bool]


def pair_rotation(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    f: int,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    camera: Camera,
    threshold_px: float = 2.0,
    pair_fit: PairFit | None = None,
) -> PairRotation | None:
    """The rotation of frame pair ``(f, f + 1)`` from its matches ``pts_a, pts_b (M, 2)``
    (arguments as :func:`rotations_from_pairs`'), ``None`` with fewer than
    :data:`MIN_POINTS` matches or inliers. Pairs are independent: they may be measured as
    they are tracked, on any thread, and gathered by :func:`collect_rotations`."""
    if len(pts_a) < MIN_POINTS:
        return None
    fx = camera.intrinsics[0]
    H = camera.height
    ba = camera.unproject(pts_a)
    bb = camera.unproject(pts_b)
    ba /= np.linalg.norm(ba, axis=1, keepdims=True)
    bb /= np.linalg.norm(bb, axis=1, keepdims=True)
    if pair_fit is None:
        R, inl = fit_rotation(ba, bb, threshold_px / fx, seed=f)
        moved = False
    else:
        R, inl, moved = pair_fit(ba, bb, threshold_px / fx, f)
    n = int(np.count_nonzero(inl))
    if n < MIN_POINTS:
        return None
    g = f + 1
    ya = float(np.mean(pts_a[inl, 1]))
    yb = float(np.mean(pts_b[inl, 1]))
    ta = frame_t_s[f] + camera.readout_s * ya / H + exposure_s[f] / 2
    tb = frame_t_s[g] + camera.readout_s * yb / H + exposure_s[g] / 2
    return ta, tb, R, n, f, bool(moved)


def collect_rotations(pairs: Sequence[PairRotation | None]) -> ImageRotations:
    """:class:`ImageRotations` of the measured pairs (``None``: not measured), in order;
    :class:`AxisSearchError` for fewer than :data:`MIN_PAIRS`."""
    got = [p for p in pairs if p is not None]
    if len(got) < MIN_PAIRS:
        raise AxisSearchError(
            f"too few frame pairs with {MIN_POINTS}+ matched points to measure rotations "
            f"({len(got)}; need {MIN_PAIRS})"
        )
    ta, tb, Rs, npts, fa, tr = zip(*got, strict=True)
    return ImageRotations(
        np.array(ta), np.array(tb), np.stack(Rs), np.array(npts), np.array(fa), np.array(tr, bool)
    )
