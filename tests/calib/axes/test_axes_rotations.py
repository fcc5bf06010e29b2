"""Rotations measured from the images (calib.axes.rotations): the robust rotation fit ignores
outliers, and its batched RANSAC equals the one-sample-at-a-time loop bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.rotation import so3_exp
from calib.axes.rotations import fit_rotation


def test_fit_rotation_ignores_outliers() -> None:
    rng = np.random.default_rng(1)
    a = rng.standard_normal((80, 3)) * [0.3, 0.2, 0] + [0, 0, 1]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    R = so3_exp(np.array([0.01, -0.03, 0.02]))
    b = a @ R.T + rng.normal(0, 1e-4, a.shape)
    b[:20] += rng.normal(0, 0.02, (20, 3))  # 25 % wrong matches
    Rf, inl = fit_rotation(a, b, 1e-3)
    assert not inl[:20].any() and inl[20:].mean() > 0.95
    assert np.degrees(np.linalg.norm(so3_exp(np.zeros(3)) - Rf.T @ R)) < 0.01


def _fit_rotation_one_sample_at_a_time(
    a: np.ndarray, b: np.ndarray, threshold_rad: float, iterations: int = 64, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """fit_rotation as first written (a Kabsch fit and inlier count per RANSAC sample)."""
    rng = np.random.default_rng(seed)

    def kabsch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        U, _, Vt = np.linalg.svd(q.T @ p)
        return U @ np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)]) @ Vt

    def inliers(R: np.ndarray) -> np.ndarray:
        return np.linalg.norm(a @ R.T - b, axis=1) < threshold_rad

    best, best_count = np.ones(len(a), dtype=bool), -1
    for _ in range(iterations):
        i = rng.choice(len(a), 2, replace=False)
        inl = inliers(kabsch(a[i], b[i]))
        if np.count_nonzero(inl) > best_count:
            best, best_count = inl, int(np.count_nonzero(inl))
    if best_count < 2:
        best = np.ones(len(a), dtype=bool)
    R = kabsch(a[best], b[best])
    inl = inliers(R)
    if np.count_nonzero(inl) >= 2:
        R = kabsch(a[inl], b[inl])
        inl = inliers(R)
    return R, inl


@pytest.mark.parametrize("seed", [0, 3])
def test_fit_rotation_equals_the_one_sample_at_a_time_ransac(seed: int) -> None:
    """The batched RANSAC gives bit for bit the loop's rotation and inliers (50 % outliers,
    so samples disagree), also with too few samples to agree across seeds."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((60, 3)) * [0.3, 0.2, 0] + [0, 0, 1]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = a @ so3_exp(rng.normal(0, 0.02, 3)).T + rng.normal(0, 3e-4, a.shape)
    b[:30] += rng.normal(0, 0.01, (30, 3))
    for gate, iters in ((1e-3, 64), (1e-3, 5), (1e-9, 8), (1e-3, 0)):
        R, inl = fit_rotation(a, b, gate, iters, seed)
        R0, inl0 = _fit_rotation_one_sample_at_a_time(a, b, gate, iters, seed)
        assert np.array_equal(R, R0) and np.array_equal(inl, inl0)
    # with two samples the result depends on which are drawn: the draws are the loop's
    few = [fit_rotation(a, b, 1e-3, 2, k)[0] for k in range(8)]
    assert len({R.tobytes() for R in few}) > 1
    for k, R in enumerate(few):
        assert np.array_equal(R, _fit_rotation_one_sample_at_a_time(a, b, 1e-3, 2, k)[0])
