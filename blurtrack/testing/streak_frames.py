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


def line(p0: Sequence[float], p1: Sequence[float], n: int = 400, accel: float = 0.0) -> np.ndarray:
    """Straight path from ``p0`` to ``p1`` sampled uniformly in time, shape ``(n, 2)``.

    ``accel`` in [-1, 1] bends the time law: position fraction ``u = t + accel * t (1 - t)``,
    so the speed falls linearly from ``1 + accel`` to ``1 - accel`` (times the mean speed).
    """
    t = np.linspace(0.0, 1.0, n)
    u = t + accel * t * (1.0 - t)
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    return a[None, :] + u[:, None] * (b - a)[None, :]
