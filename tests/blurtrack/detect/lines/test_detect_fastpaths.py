"""The fast paths of detection agree with their plain definitions (hot pixels, short fits)."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
from scipy.special import ndtr

from blurtrack.detect.image import background_and_noise, remove_hot_pixels, sparse_points
from blurtrack.detect.lines import ragged
from blurtrack.detect.lines.centreline import _centre_shift, cross_section_sigma, tail_sigma
from blurtrack.detect.lines.ragged import row_nanmedian
from blurtrack.detect.lines.segment import find_components
from blurtrack.detect.lines.shortfit import _basis, fit_short
from blurtrack.errors import DetectionError

_RING = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]


def _hot_reference(
    raw: np.ndarray, signal: np.ndarray, ratio: float, floor: float
) -> tuple[np.ndarray, np.ndarray]:
    """The definition, pixel by pixel: interior raw local maxima above ``floor`` that exceed
    ``ratio`` times their brightest 8-neighbour; returns the hot mask and the repaired signal."""
    H, W = raw.shape
    hot = np.zeros((H, W), bool)
    out = signal.copy()
    for y in range(1, H - 1):
        for x in range(1, W - 1):
            nb = [raw[y + dy, x + dx] for dy, dx in _RING]
            ring = max(signal[y + dy, x + dx] for dy, dx in _RING)
            v = signal[y, x]
            if raw[y, x] >= max(nb) and v > floor and v > ratio * max(ring, 0.0):
                hot[y, x] = True
                out[y, x] = ring
    return hot, out


def _frame_with_hot_pixels(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A noisy frame on a sloped background with Gaussian dots and single bright pixels:
    raw, its signal and the background."""
    rng = np.random.default_rng(seed)
    H, W = 48, 64
    yy, xx = np.mgrid[0:H, 0:W]
    bg = (20.0 + 0.15 * xx + 0.1 * yy).astype(np.float32)
    img = bg + rng.normal(0.0, 2.0, (H, W))
    for _ in range(6):  # Gaussian dots (sigma 1.2 px): never hot
        cx, cy = rng.uniform(4, W - 4), rng.uniform(4, H - 4)
        img += 150.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 1.2**2))
    for _ in range(10):  # single bright pixels, some on the border (never replaced)
        img[rng.integers(0, H), rng.integers(0, W)] = rng.uniform(60, 255)
    raw = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    signal = (raw.astype(np.float32) - bg) / 255.0
    return raw, signal, bg


def test_hot_pixel_removal_equals_its_definition() -> None:
    for seed in range(4):
        raw, signal, bg = _frame_with_hot_pixels(seed)
        for floor in (0.05, 0.2):
            hot, expected = _hot_reference(raw, signal, 3.0, floor)
            assert hot.sum() >= 2
            # The floor tested on the signal, or first on the raw frame (lowest background).
            for raw_floor in (None, floor * 255.0 + float(bg.min()) - 0.01):
                fast = signal.copy()
                count = remove_hot_pixels(raw, fast, 3.0, floor, raw_floor)
                assert count == int(hot.sum())
                np.testing.assert_array_equal(fast, expected)


def test_hot_pixel_removal_without_candidates_changes_nothing() -> None:
    raw = np.full((16, 16), 7, np.uint8)
    signal = np.zeros((16, 16), np.float32)
    assert remove_hot_pixels(raw, signal, 3.0, 0.01) == 0
    assert not signal.any()


def test_basis_derivatives_match_finite_differences() -> None:
    s = np.arange(30, dtype=np.float64)[None, :]
    a, L, sg = np.array([8.3, 10.0]), np.array([6.2, 1.0]), np.array([1.8, 2.5])
    h = 1e-6
    F0, F1, F2, ga, gb = _basis(s, a, L, sg)
    F0a, F1a, F2a, _, _ = _basis(s, a + h, L, sg)
    F0l, F1l, F2l, _, _ = _basis(s, a, L + h, sg)
    half_L = 0.5 * L[:, None]
    # The basis uses A&S 7.1.26 for Phi, whose slope is the Gaussian density to 3e-6.
    np.testing.assert_allclose((F0a - F0) / h, gb - ga, atol=5e-6)
    np.testing.assert_allclose((F1a - F1) / h, -F0 + (ga + gb) * half_L, atol=1e-5)
    np.testing.assert_allclose((F2a - F2) / h, -2 * F1 + (gb - ga) * half_L**2, atol=1e-5)
    np.testing.assert_allclose((F0l - F0) / h, gb, atol=5e-6)
    np.testing.assert_allclose((F1l - F1) / h, -0.5 * F0 + gb * half_L, atol=1e-5)
    np.testing.assert_allclose((F2l - F2) / h, -F1 + gb * half_L**2, atol=1e-5)


def test_basis_is_the_blur_of_the_density_moments() -> None:
    # F_k(s) = integral over the segment of (u - mid)**k g(s - u) du, by dense quadrature.
    s = np.arange(25, dtype=np.float64)[None, :]
    a, L, sg = np.array([7.4]), np.array([9.3]), np.array([1.7])
    F = _basis(s, a, L, sg)[:3]
    u = np.linspace(a[0], a[0] + L[0], 20001)
    g = np.exp(-0.5 * ((s[0][:, None] - u[None, :]) / sg[0]) ** 2) / (sg[0] * np.sqrt(2 * np.pi))
    for k in range(3):
        ref = np.trapezoid(g * (u - u.mean())[None, :] ** k, u, axis=1)
        # Phi to 1e-7 (A&S 7.1.26), times (s - mid)**k <= 150 in F2.
        np.testing.assert_allclose(F[k][0], ref, atol=2e-7 * 12.0 ** (2 * k))


def test_fit_short_recovers_noise_free_segments() -> None:
    # Blurred segments of uniform, linearly and quadratically varying density, fitted from
    # rough starts.
    s = np.arange(40, dtype=np.float64)
    a_true = np.array([12.0, 15.3, 18.7, 11.2])
    L_true = np.array([6.0, 3.4, 9.1, 11.5])
    slope = np.array([0.0, 0.0, 0.15, -0.08])  # density 1 + slope u + curv u**2 (u - mid)
    curv = np.array([0.0, 0.0, 0.0, 0.03])
    sigma = np.array([1.8, 1.8, 2.0, 1.7])
    y = np.zeros((4, s.size))
    for i in range(4):
        u = np.linspace(a_true[i], a_true[i] + L_true[i], 4001)
        dens = 1.0 + slope[i] * (u - u.mean()) + curv[i] * (u - u.mean()) ** 2
        g = np.exp(-0.5 * ((s[:, None] - u[None, :]) / sigma[i]) ** 2)
        g /= sigma[i] * np.sqrt(2 * np.pi)
        y[i] = np.trapezoid(g * dens[None, :], u, axis=1)
    w = np.ones_like(y)
    a, L, c0 = fit_short(
        y,
        w,
        sigma,
        a_true + np.array([0.6, -0.5, 0.8, -0.5]),
        L_true + np.array([-1.0, 1.2, -0.9, 0.8]),
        iterations=6,
    )
    np.testing.assert_allclose(a, a_true, atol=3e-3)
    np.testing.assert_allclose(L, L_true, atol=5e-3)
    # The mean density over the segment.
    np.testing.assert_allclose(c0, 1.0 + curv * L_true**2 / 12, atol=3e-3)
    # A pure edge step (not a segment) stays finite and inside the window.
    edge = np.tile(ndtr((s - 20.0) / 1.8), (1, 1))
    a2, L2, _ = fit_short(
        edge, np.ones_like(edge), np.array([1.8]), np.array([18.0]), np.array([5.0])
    )
    assert np.isfinite(a2).all() and a2[0] >= 0 and a2[0] + L2[0] <= 39.0 + 1e-9


def test_cross_section_widths_of_sampled_gaussians() -> None:
    half = 7
    o = np.arange(-half, half + 1, dtype=np.float64)
    sig = np.array([1.2, 1.7, 2.6])
    shift = np.array([0.0, 0.3, -0.45])
    v = 0.8 * np.exp(-0.5 * ((o[None, :] - shift[:, None]) / sig[:, None]) ** 2)
    np.testing.assert_allclose(cross_section_sigma(v, half), sig, rtol=1e-9)
    # Centred and clipped at 40 % of the peak: the flanks still give the width.
    centred = 0.8 * np.exp(-0.5 * (o[None, :] / sig[:, None]) ** 2)
    np.testing.assert_allclose(tail_sigma(np.minimum(centred, 0.32), half, 0.32), sig, rtol=1e-9)
    # Unusable rows are nan: a dip in the middle, too few flank samples.
    flat = np.ones((1, 2 * half + 1))
    assert np.isnan(cross_section_sigma(-v[:1], half)).all()
    assert np.isnan(tail_sigma(flat, half, 0.5)).all()
    # The centroid of the central window (negative samples as 0), clipped to the limit.
    w = np.maximum(v[:, half - 3 : half + 4] - 0.05, 0.0)
    expected = np.clip(w @ o[half - 3 : half + 4] / w.sum(axis=1), -0.2, 0.2)
    np.testing.assert_allclose(_centre_shift(v - 0.05, 3, 0.2), expected, rtol=1e-12)
    c = _centre_shift(v, 3, 1.0)
    assert abs(c[0]) < 1e-12 and np.all(np.sign(c[1:]) == np.sign(shift[1:]))


def test_row_nanmedian_equals_numpy() -> None:
    rng = np.random.default_rng(3)
    X = rng.normal(size=(120, 17))
    X[rng.random(X.shape) < 0.6] = np.nan
    X[5] = np.nan  # a row without any value
    X[7, :] = 2.0  # ties
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanmedian(X, axis=1)
    np.testing.assert_array_equal(row_nanmedian(X), expected)
    assert row_nanmedian(np.zeros((0, 4))).shape == (0,)


def test_too_many_blobs_is_an_error_not_a_label_overflow() -> None:
    # 67600 separate pixels: more than 16-bit labels hold, so the 32-bit path runs and the
    # streak cap rejects the frame.
    smooth = np.zeros((520, 520), np.float32)
    smooth[::2, ::2] = 1.0
    with pytest.raises(DetectionError):
        find_components(smooth, 0.5, 1, 5000)
    comps = find_components(smooth[:40, :40], 0.5, 1, 5000)
    assert comps.ids.size == 400 and np.all(comps.areas == 1)


def test_tangents_are_clamped_central_differences() -> None:
    rng = np.random.default_rng(0)
    lines = [rng.normal(size=(n, 2)).cumsum(axis=0) for n in rng.integers(2, 30, 60)]
    r = ragged.Ragged.from_list(lines)
    t = ragged.tangents(r)
    for k, line in enumerate(lines):
        i = np.arange(len(line))
        d = line[np.minimum(i + 1, len(line) - 1)] - line[np.maximum(i - 1, 0)]
        expected = d / np.linalg.norm(d, axis=1, keepdims=True)
        np.testing.assert_allclose(t[r.starts[k] : r.starts[k] + len(line)], expected, atol=1e-12)


def test_hot_pixel_on_a_noise_free_flat_frame() -> None:
    # Every background pixel is a local maximum here; only the floor rules them out. On a
    # flat frame even one count above the background beats 3x its (zero) neighbours.
    raw = np.full((30, 40), 20, np.uint8)
    raw[12, 17] = 200
    raw[5, 30] = 21
    signal = (raw.astype(np.float32) - 20.0) / 255.0
    floor = 5 * 1e-4
    hot, expected = _hot_reference(raw, signal, 3.0, floor)
    assert int(hot.sum()) == 2
    for raw_floor in (None, floor * 255.0 + 20.0 - 0.01):
        s = signal.copy()
        assert remove_hot_pixels(raw, s, 3.0, floor, raw_floor) == 2
        np.testing.assert_array_equal(s, expected)


def _background_reference(gray: np.ndarray) -> tuple[float, float]:
    """The definition on the sorted sample: median, scaled MAD, mean and sigma of the core."""
    step = max(1, int(np.sqrt(gray.size / 12000)))
    sample = gray[::step, ::step].ravel().astype(np.float64)
    median = float(np.median(sample))
    sigma0 = max(1.4826 * float(np.median(np.abs(sample - median))), 0.5)
    core = sample[np.abs(sample - median) <= 4.0 * sigma0 + 1.0]
    return float(np.mean(core)), float(np.std(core))


def test_background_from_the_histogram_equals_the_sorted_sample() -> None:
    rng = np.random.default_rng(2)
    frames = [
        rng.integers(0, 256, (100, 131)).astype(np.uint8),  # odd and even sample sizes
        rng.integers(0, 256, (100, 130)).astype(np.uint8),
        np.clip(rng.normal(20.0, 2.0, (200, 300)), 0, 255).astype(np.uint8),
        np.full((40, 40), 7, np.uint8),
    ]
    dots = frames[2].copy()
    dots[::9, ::7] = 250  # sparse bright pixels: outside the core
    frames.append(dots)
    for gray in frames:
        np.testing.assert_allclose(
            background_and_noise(gray), _background_reference(gray), rtol=1e-12, atol=1e-12
        )
    wide = rng.integers(0, 4096, (90, 90)).astype(np.uint16)  # 16-bit: the sorted path
    np.testing.assert_allclose(background_and_noise(wide), _background_reference(wide))


def test_sparse_points_match_find_non_zero() -> None:
    rng = np.random.default_rng(4)
    for shape, density in (((72, 128), 0.002), ((72, 128), 0.3), ((31, 17), 0.01)):
        mask = (rng.random(shape) < density).astype(np.uint8) * 255
        mask[0, 0] = 1
        count = cv2.countNonZero(mask)
        ys, xs = sparse_points(mask, count)
        nz = cv2.findNonZero(mask).reshape(-1, 2)
        np.testing.assert_array_equal(ys, nz[:, 1])
        np.testing.assert_array_equal(xs, nz[:, 0])


def _smooth_reference(line: np.ndarray) -> np.ndarray:
    """[1 4 6 4 1]/16 over one line continued by point reflection through its end points
    (reflected indices clamped to the line)."""
    n = len(line)
    out = np.empty_like(line)
    for i in range(n):
        acc = 6.0 * line[i]
        for off, w in ((-2, 1.0), (-1, 4.0), (1, 4.0), (2, 1.0)):
            j = i + off
            if j < 0:
                q = 2 * line[0] - line[min(-j, n - 1)]
            elif j > n - 1:
                q = 2 * line[-1] - line[max(2 * (n - 1) - j, 0)]
            else:
                q = line[j]
            acc = acc + w * q
        out[i] = acc / 16.0
    return out


def test_smooth_equals_per_line_reflection() -> None:
    rng = np.random.default_rng(6)
    lines = [rng.normal(size=(n, 2)).cumsum(axis=0) for n in rng.integers(2, 12, 50)]
    out = ragged.smooth(ragged.Ragged.from_list(lines)).split()
    for got, line in zip(out, lines, strict=True):
        np.testing.assert_allclose(got, _smooth_reference(line), atol=1e-12)
        if len(line) >= 3:
            np.testing.assert_allclose(got[[0, -1]], line[[0, -1]], atol=1e-12)
