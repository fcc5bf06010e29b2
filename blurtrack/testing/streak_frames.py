"""Small synthetic laser-dot frames with known truth, for tests, examples and the demo.

A dot is a Gaussian spot (sigma in px) moved along a curve during the exposure; the image is
the time integral of the pixel-integrated spot, so the brightness per unit length is inversely
proportional to the dot's speed, as on the real rig. Curves are given as positions sampled
uniformly in time, shape ``(T, 2)`` (x, y) in pixels, pixel (0, 0) being the centre of the
top-left pixel. This is a reference renderer, written for exactness rather than speed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.special import ndtr

from blurtrack.errors import DetectionError


def _pixel_weights(centres: np.ndarray, lo: int, n: int, sigma: float) -> np.ndarray:
    """Pixel-integrated 1-D Gaussian weights, shape ``(T, n)`` for pixels ``lo .. lo+n-1``."""
    edges = np.arange(lo, lo + n + 1, dtype=np.float64) - 0.5
    cdf = ndtr((edges[None, :] - centres[:, None]) / sigma)
    return np.diff(cdf, axis=1)


def render_streaks(
    shape: tuple[int, int],
    curves: Sequence[np.ndarray],
    flux_per_px: float | Sequence[float] | np.ndarray = 2.0,
    sigma_px: float = 1.5,
    background: float = 0.02,
    noise: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Render streaks into a float image in full-scale units (1.0 = white), not clipped.

    Args:
        shape: ``(H, W)``.
        curves: per dot, positions ``(T, 2)`` sampled uniformly over the exposure (T >= 2);
            consecutive samples should be closer than ~0.3 px.
        flux_per_px: integrated brightness per px of path at the streak's average speed
            (the plateau's peak value is about ``flux_per_px / (sigma_px * sqrt(2 pi))``).
        sigma_px: dot spread.
        background, noise: constant background level and Gaussian noise sigma.
    Returns:
        ``(H, W)`` float64 image.
    """
    H, W = shape
    image = np.full((H, W), float(background))
    fluxes = np.broadcast_to(np.asarray(flux_per_px, dtype=np.float64), (len(curves),))
    pad = int(np.ceil(5 * sigma_px)) + 1
    for curve, flux in zip(curves, fluxes, strict=True):
        pts = np.asarray(curve, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise DetectionError("a synthetic curve must be a (T>=2, 2) array")
        length = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
        total = flux * max(length, 1.0)
        x0 = max(int(np.floor(pts[:, 0].min())) - pad, 0)
        x1 = min(int(np.ceil(pts[:, 0].max())) + pad, W - 1)
        y0 = max(int(np.floor(pts[:, 1].min())) - pad, 0)
        y1 = min(int(np.ceil(pts[:, 1].max())) + pad, H - 1)
        if x1 < x0 or y1 < y0:
            continue  # entirely outside the frame
        gx = _pixel_weights(pts[:, 0], x0, x1 - x0 + 1, sigma_px)
        gy = _pixel_weights(pts[:, 1], y0, y1 - y0 + 1, sigma_px)
        image[y0 : y1 + 1, x0 : x1 + 1] += (gy.T * (total / len(pts))) @ gx
    if noise > 0:
        image += np.random.default_rng(seed).normal(0.0, noise, size=image.shape)
    return image


def quantise(image: np.ndarray, dtype: type = np.uint8) -> np.ndarray:
    """Clip a full-scale float image to [0, 1] and quantise it to ``uint8`` or ``uint16``."""
    top = float(np.iinfo(dtype).max)
    return np.clip(np.rint(image * top), 0, top).astype(dtype)


def line(
    p0: Sequence[float] | np.ndarray,
    p1: Sequence[float] | np.ndarray,
    n: int = 400,
    accel: float = 0.0,
) -> np.ndarray:
    """Straight path from ``p0`` to ``p1`` sampled uniformly in time, shape ``(n, 2)``.

    ``accel`` in [-1, 1] bends the time law: position fraction ``u = t + accel * t (1 - t)``,
    so the speed falls linearly from ``1 + accel`` to ``1 - accel`` (times the mean speed).
    """
    t = np.linspace(0.0, 1.0, n)
    u = t + accel * t * (1.0 - t)
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    return a[None, :] + u[:, None] * (b - a)[None, :]


def line_grid(
    count: int,
    cols: int,
    origin: Sequence[float],
    spacing: Sequence[float],
    vector: Sequence[float],
) -> list[np.ndarray]:
    """``count`` dots' streaks on a grid of ``cols`` columns, row by row: streak ``k`` is the
    :func:`line` from ``origin + (k % cols, k // cols) * spacing`` along ``vector`` (px),
    every dot drawing the same path."""
    x0, y0 = (float(v) for v in origin)
    dx, dy = (float(v) for v in spacing)
    d = np.asarray(vector, float)
    out = []
    for k in range(count):
        p0 = np.array([x0 + dx * (k % cols), y0 + dy * (k // cols)])
        out.append(line(p0, p0 + d))
    return out


def saturated_grid(
    peak: float,
    accel: float = 0.0,
    sigma_px: float = 1.5,
    length_px: float = 50.0,
    seed: int = 3,
) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """A 400 x 700 8-bit frame of 24 straight streaks (a 4 x 6 grid, 100 x 90 px apart,
    directions within +-0.4 rad of the rows, :func:`line` with ``accel``), rendered exactly
    (PSF ``sigma_px``, background 0.03, noise 0.004 of full scale) with a plateau peak of
    ``peak`` times the saturation; with each streak's true start and end (px)."""
    rng = np.random.default_rng(seed)
    curves, truth = [], []
    for i in range(4):
        for j in range(6):
            p0 = np.array([60.0 + j * 100.0, 60.0 + i * 90.0])
            ang = rng.uniform(-0.4, 0.4)
            p1 = p0 + length_px * np.array([np.cos(ang), np.sin(ang)])
            curves.append(line(p0, p1, 800, accel))
            truth.append((p0, p1))
    flux = peak * sigma_px * np.sqrt(2.0 * np.pi)  # render_streaks' plateau peak
    image = render_streaks((400, 700), curves, flux, sigma_px, 0.03, 0.004, seed=1)
    return quantise(image), truth


def outward_errors(
    end_a: np.ndarray, end_b: np.ndarray, truth: Sequence[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """Per true streak ``(start, end)`` of ``truth``: how far the detection nearest it
    (``end_a``, ``end_b`` ``(N, 2)``, either orientation) lies beyond its true start and
    beyond its true end, along the streak (px; negative: inside). Two ``(len(truth),)``
    arrays."""
    A, B = np.asarray(end_a, float), np.asarray(end_b, float)
    start_out, end_out = [], []
    for p0, p1 in truth:
        d = np.minimum(
            np.hypot(*(A - p0).T) + np.hypot(*(B - p1).T),
            np.hypot(*(A - p1).T) + np.hypot(*(B - p0).T),
        )
        k = int(np.argmin(d))
        a, b = (A[k], B[k]) if np.hypot(*(A[k] - p0)) < np.hypot(*(A[k] - p1)) else (B[k], A[k])
        u = (p1 - p0) / np.hypot(*(p1 - p0))
        start_out.append(-float(np.dot(a - p0, u)))
        end_out.append(float(np.dot(b - p1, u)))
    return np.asarray(start_out), np.asarray(end_out)
