"""blurtrack.features.blur_estimate: blur measured from a single tile (cepstrum)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.features.blur_estimate import (
    BlurEstimateError,
    endpoint_difference,
    estimate_blur_vector,
    fft_size,
    kernel_cepstrum,
    kernel_score,
    rasterize,
    tile_cepstrum,
)

R = 30


def _scene(seed: int, n: int = 224) -> np.ndarray:
    """A 1/f (natural-image-like) random scene."""
    rng = np.random.default_rng(seed)
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n))) + 1.0 / n
    return np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) / f).real


def _blur(scene: np.ndarray, traj: np.ndarray, noise: float, seed: int) -> np.ndarray:
    k = rasterize(traj, 2 * R + 1)
    b = cv2.filter2D(scene, -1, k, borderType=cv2.BORDER_REFLECT)[R + 2 : -R - 2, R + 2 : -R - 2]
    b = (b - b.min()) / np.ptp(b)
    return b + np.random.default_rng(seed).normal(0.0, noise, b.shape)


def _curve(v: np.ndarray, bow: float, n: int = 16) -> np.ndarray:
    tau = np.linspace(0.0, 1.0, n)[:, None]
    normal = np.array([-v[1], v[0]]) / np.hypot(*v)
    return tau * v + 4 * tau * (1 - tau) * bow * normal


@pytest.mark.parametrize(
    ("vector", "seed"), [((16.0, 9.0), 1), ((-7.0, 20.0), 2), ((24.0, -3.0), 3)]
)
def test_straight_blur_vector_recovered(vector: tuple[float, float], seed: int) -> None:
    v = np.array(vector)
    tile = _blur(_scene(seed), np.stack([0 * v, v]), noise=0.005, seed=seed)
    est = estimate_blur_vector(tile, radius=R)
    assert est is not None
    err = float(endpoint_difference(np.array(est.vector_px), v))
    assert err < 1.5, (est, vector)
    assert est.length_px == pytest.approx(np.hypot(*v), abs=1.5)
    # sign-free: the estimate is reported with dy >= 0
    assert est.vector_px[1] >= 0


def test_curved_kernel_scores_above_wrong_kernels() -> None:
    v = np.array([18.0, 8.0])
    traj = _curve(v, bow=5.0)
    tile = _blur(_scene(7), traj, noise=0.005, seed=7)
    tmap = tile_cepstrum(tile, R)
    assert tmap is not None
    n = fft_size(tile.shape)

    def score(t: np.ndarray) -> float:
        return kernel_score(tmap, kernel_cepstrum(rasterize(t, 2 * R + 1), R, n))

    rot90 = traj @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    half = traj[: traj.shape[0] // 2 + 1]  # the first half of the exposure only
    true = score(traj)
    assert true > 0.15
    assert true > score(rot90) + 0.1
    assert true > score(half) + 0.05
    # the straight chord scores below the true curved path
    assert true > score(np.stack([traj[0], traj[-1]]))


def test_flat_tile_is_undetermined() -> None:
    assert tile_cepstrum(np.full((128, 128), 0.4), R) is None
    assert estimate_blur_vector(np.zeros((128, 128)), radius=R) is None


def test_white_noise_scores_far_below_a_blurred_tile() -> None:
    """No blur to see: the best straight line explains white noise far worse than it explains
    a blurred scene with the same noise; with the default thresholds it is undetermined."""
    rng = np.random.default_rng(5)
    noise = 0.5 + rng.normal(0.0, 0.05, (128, 128))
    v = np.array([16.0, 9.0])
    blurred = _blur(_scene(1), np.stack([0 * v, v]), noise=0.005, seed=1)
    est_noise = estimate_blur_vector(noise, radius=R, min_score=-1.0, min_margin=-1.0)
    est_blur = estimate_blur_vector(blurred, radius=R, min_score=-1.0, min_margin=-1.0)
    assert est_noise is not None and est_blur is not None
    assert est_blur.score > 2 * est_noise.score
    assert est_blur.margin > 2 * est_noise.margin
    assert estimate_blur_vector(noise, radius=R) is None


@pytest.mark.parametrize(
    "bad",
    [np.ones(10), np.ones((6, 6)), np.full((64, 64), np.nan)],
)
def test_bad_tiles_raise(bad: np.ndarray) -> None:
    with pytest.raises(BlurEstimateError):
        tile_cepstrum(bad, 16)


def test_bad_kernels_and_maps_raise() -> None:
    with pytest.raises(BlurEstimateError, match="odd"):
        rasterize(np.array([[0.0, 0.0], [3.0, 0.0]]), 8)
    with pytest.raises(BlurEstimateError, match="fit"):
        rasterize(np.array([[0.0, 0.0], [30.0, 0.0]]), 9)
    with pytest.raises(BlurEstimateError):
        kernel_cepstrum(np.zeros((9, 9)), 4, 64)
    with pytest.raises(BlurEstimateError, match="equal"):
        kernel_score(np.zeros((9, 9)), np.zeros((11, 11)))
