"""Frame preparation: conversion to float gray, background and noise level, hot pixels."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.errors import DetectionError

_OFFSETS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@dataclass(frozen=True)
class PreparedFrame:
    """A frame ready for segmentation (all intensities in full-scale units, 1.0 = white).

    - ``signal``: ``(H, W)`` float32, background subtracted, hot pixels removed.
    - ``smooth``: ``signal`` after the Gaussian pre-smoothing.
    - ``saturated``: ``(H, W)`` bool, raw pixels at or above the saturation level.
    - ``background``, ``noise``: the frame's background level and raw noise sigma.
    - ``noise_smooth``: noise sigma of ``smooth``.
    - ``saturation``: the saturation level in ``signal`` units (after background subtraction).
    - ``hot_pixels``: how many hot pixels were replaced.
    """

    signal: np.ndarray
    smooth: np.ndarray
    saturated: np.ndarray
    background: float
    noise: float
    noise_smooth: float
    saturation: float
    hot_pixels: int


def to_gray_float(
    image: np.ndarray, saturation_level: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Convert a stored frame to float32 gray in full-scale units and flag saturated pixels.

    Accepts ``uint8`` or ``uint16``, gray ``(H, W)`` or colour ``(H, W, 3|4)`` (BGR[A]). Colour
    uses the brightest channel, so a laser of any colour keeps its full contrast and its
    saturation is seen. Returns ``(gray (H, W) float32, saturated (H, W) bool)``.
    """
    if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
        raise DetectionError("a frame must be a 2-D gray or 3-D colour array")
    if image.dtype not in (np.uint8, np.uint16):
        raise DetectionError(f"unsupported frame dtype {image.dtype} (need uint8 or uint16)")
    if image.ndim == 3:
        if image.shape[2] not in (1, 3, 4):
            raise DetectionError(f"unsupported number of channels {image.shape[2]}")
        image = image[:, :, :3].max(axis=2) if image.shape[2] > 1 else image[:, :, 0]
    if min(image.shape) < 8:
        raise DetectionError(f"frame too small: {image.shape}")
    top = float(np.iinfo(image.dtype).max)
    level = top if saturation_level is None else float(saturation_level)
    saturated = image >= level
    gray = image.astype(np.float32) * np.float32(1.0 / top)
    return gray, saturated


def background_and_noise(gray: np.ndarray) -> tuple[float, float]:
    """Robust background level (median) and noise sigma (scaled MAD) of a sparse-dot frame.

    Uses a regular sub-sample, so that the cost does not grow with the frame. Dots cover a
    small fraction of a laser-grid frame, so both statistics see the background.
    """
    step = max(1, int(np.sqrt(gray.size / 12000)))
    sample = gray[::step, ::step].ravel()
    background = float(np.median(sample))
    mad = float(np.median(np.abs(sample - background)))
    noise = 1.4826 * mad
    if noise == 0.0:
        # Quantised, nearly noise-free frames: use the spread of the lower half instead.
        low = sample[sample <= background]
        noise = float(np.std(low)) if low.size else 0.0
    return background, max(noise, 1e-4)


def remove_hot_pixels(signal: np.ndarray, ratio: float, floor: float) -> int:
    """Replace isolated hot pixels in place; return how many were replaced.

    A hot pixel exceeds ``floor`` and is more than ``ratio`` times brighter than its brightest
    8-neighbour. A real dot (sigma >= ~0.7 px) always has a neighbour at more than a third of its
    peak, so it never qualifies. Only pixels above ``floor`` are examined (they are few).
    """
    nz = cv2.findNonZero((signal[1:-1, 1:-1] > floor).view(np.uint8))
    if nz is None:
        return 0
    nz = nz.reshape(-1, 2).astype(np.int64) + 1
    xs, ys = nz[:, 0], nz[:, 1]
    ring = np.stack([signal[ys + dy, xs + dx] for dy, dx in _OFFSETS], axis=1).max(axis=1)
    hot = signal[ys, xs] > ratio * np.maximum(ring, 0.0)
    count = int(np.count_nonzero(hot))
    if count:
        signal[ys[hot], xs[hot]] = ring[hot]
    return count


def prepare_frame(
    image: np.ndarray,
    smooth_sigma_px: float,
    hot_pixel_ratio: float,
    saturation_level: float | None = None,
) -> PreparedFrame:
    """Convert, subtract the background, remove hot pixels and pre-smooth a frame."""
    gray, saturated = to_gray_float(image, saturation_level)
    if not np.all(np.isfinite(gray)):
        raise DetectionError("frame contains non-finite values")
    background, noise = background_and_noise(gray)
    signal = gray - np.float32(background)
    hot = remove_hot_pixels(signal, hot_pixel_ratio, 5.0 * noise)
    smooth = cv2.GaussianBlur(signal, (0, 0), smooth_sigma_px, borderType=cv2.BORDER_REPLICATE)
    # Noise of white noise after a Gaussian blur of sigma s: sigma / (2 sqrt(pi) s).
    noise_smooth = noise / (2.0 * np.sqrt(np.pi) * smooth_sigma_px)
    top = float(np.iinfo(image.dtype).max)
    sat_level = (top if saturation_level is None else float(saturation_level)) / top
    return PreparedFrame(
        signal=signal,
        smooth=smooth,
        saturated=saturated,
        background=background,
        noise=noise,
        noise_smooth=float(noise_smooth),
        saturation=sat_level - background,
        hot_pixels=hot,
    )
