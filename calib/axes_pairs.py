"""One frame pair's image rotation at a time (:func:`pair_rotation`) and the
:class:`~calib.axes.ImageRotations` gathered from them (:func:`collect_rotations`).

:func:`calib.axes.rotations_from_pairs` measures the pairs of a finished track set with these;
a natural calibration measures each pair on the tracking thread that has just tracked it
(:mod:`calib.natural_pairs`), so the rotations cost no time of their own. A pair's rotation
depends only on its own matches (its RANSAC seed is its frame index), so both give the same
values.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from blurtrack.geometry.camera import Camera
from calib.axes import (
    MIN_PAIRS,
    MIN_POINTS,
    AxisSearchError,
    ImageRotations,
    PairFit,
    fit_rotation,
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
