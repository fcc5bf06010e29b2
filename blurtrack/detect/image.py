"""Frame preparation: conversion to float gray, background and noise level, hot pixels."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from blurtrack.errors import DetectionError

_BOX = np.ones((3, 3), np.uint8)  # the 8-neighbourhood (and centre) for local maxima
#: Block size (px) of the background map: large against a streak's width (the trimmed mean per
#: block sees past the streaks), small against vignetting and ambient gradients.
BACKGROUND_BLOCK_PX = 32
#: How a colour frame becomes one channel (``DetectParams.colour``): ``auto``, the luma of the
#: light's colour where the frame's light is one colour (:func:`light_colour`), else the
#: brightest channel per pixel; ``max``, always the brightest channel per pixel.
COLOURS = ("auto", "max")
#: Luma's weights (B, G, R; ITU-R BT.601): the Y that JPEG, H.264 and H.265 store at full
#: resolution, while they store the colour differences at half of it in each direction (4:2:0
#: chroma subsampling: a red laser's red channel is mostly colour difference).
LUMA_BGR = (0.114, 0.587, 0.299)
#: A frame's light is one colour where, over half of the bright pixels, its strongest channel
#: carries more than this times the light of each other channel. A laser's light reaches the
#: other channels only through the colour filters' overlap and the demosaicing and chroma
#: subsampling that mix neighbouring pixels (the simulated red laser through an RGGB sensor and
#: JPEG: 2.4-4.0 at the median); a white or warm light's channels lie within a factor of about
#: 1.5 of each other after white balance (the real night photographs: 0.9-1.5).
ONE_COLOUR_RATIO = 2.0
#: ... and that channel is the strongest of at least this share of the bright pixels (lights of
#: two colours are not one colour, whichever holds more of the bright pixels).
ONE_COLOUR_SHARE = 0.9
#: The bright pixels: unsaturated, and above this fraction of the way from the background to
#: the frame's 99.9th percentile (the lights' cores, least mixed with their surroundings by
#: demosaicing and chroma subsampling).
BRIGHT_FRACTION = 0.75
#: Fewest bright pixels that tell the light's colour (a few dots' cores).
BRIGHT_MIN_PX = 50


class FrameLight(NamedTuple):
    """A colour frame's light of one colour (:func:`light_colour`): ``colour_bgr`` ``(3,)``
    relative to its strongest channel, and the frame's background ``background_bgr`` ``(3,)``
    (raw units, each channel's median over a sparse sample)."""

    colour_bgr: np.ndarray
    background_bgr: np.ndarray


_DY = np.array([-1, -1, -1, 0, 0, 1, 1, 1])  # the 8-neighbour ring (row offsets)
_DX = np.array([-1, 0, 1, -1, 1, -1, 0, 1])  # ... (column offsets)


@dataclass(frozen=True)
class PreparedFrame:
    """A frame ready for segmentation (all intensities in full-scale units, 1.0 = white).

    - ``signal``: ``(H, W)`` float32, background subtracted, hot pixels removed.
    - ``smooth``: ``signal`` after the Gaussian pre-smoothing.
    - ``saturated``: ``(H, W)`` bool, raw pixels at or above the saturation level (a
      ``(1, 1)`` False array when there are none).
    - ``background``, ``noise``: the frame's background level and raw noise sigma.
    - ``noise_smooth``: noise sigma of ``smooth``.
    - ``saturation``: the saturation level in ``signal`` units (after background subtraction).
    - ``hot_pixels``: how many hot pixels were replaced.
    - ``light_bgr``: the colour (B, G, R, relative to its strongest channel) of a colour
      frame's one-colour light, where the frame was measured on that light's luma
      (:func:`to_gray`); None otherwise.
    """

    signal: np.ndarray
    smooth: np.ndarray
    saturated: np.ndarray
    background: float
    noise: float
    noise_smooth: float
    saturation: float
    hot_pixels: int
    light_bgr: tuple[float, float, float] | None = None


def to_gray(image: np.ndarray, colour: str = "auto") -> np.ndarray:
    """Validate a stored frame and reduce it to one channel, keeping its dtype.

    Accepts ``uint8`` or ``uint16``, gray ``(H, W)`` or colour ``(H, W, 3|4)`` (BGR[A]).
    ``colour`` (:data:`COLOURS`): ``auto`` takes the luma of the frame's light where that light
    is one colour (a laser, :func:`light_colour`), scaled so that the light's strongest
    channel keeps its values and clipped at the dtype's maximum where that channel saturates:
    luma is the one component compressed frames keep at full resolution, and it averages the
    channels' noise. Otherwise (lights of several colours, or ``max``) it takes the brightest
    channel of each pixel, so that a light of any colour keeps its full contrast and its
    saturation is seen (the maximum of the channels' noise raises faint light, which moves a
    streak's half-level ends outwards by ~0.1 px on the simulated red laser).
    """
    return _gray_and_light(image, colour)[0]


def _gray_and_light(image: np.ndarray, colour: str) -> tuple[np.ndarray, FrameLight | None]:
    """:func:`to_gray`'s frame and the light whose luma it is (None: the brightest channel,
    or a gray frame)."""
    light: FrameLight | None = None
    if not isinstance(image, np.ndarray) or image.ndim not in (2, 3):
        raise DetectionError("a frame must be a 2-D gray or 3-D colour array")
    if image.dtype not in (np.uint8, np.uint16):
        raise DetectionError(f"unsupported frame dtype {image.dtype} (need uint8 or uint16)")
    if colour not in COLOURS:
        raise DetectionError(f"colour must be one of {COLOURS}, got {colour!r}")
    if image.ndim == 3 and image.shape[2] not in (1, 3, 4):
        raise DetectionError(f"unsupported number of channels {image.shape[2]}")
    if min(image.shape[:2]) < 8:
        raise DetectionError(f"frame too small: {image.shape[:2]}")
    if image.ndim == 3:
        if image.shape[2] == 1:
            image = image[:, :, 0]
        else:
            bgr = image[:, :, :3]
            brightest = _brightest(bgr)
            light = _one_colour(bgr, brightest) if colour == "auto" else None
            image = brightest if light is None else _luma_of(bgr, light)
    return np.ascontiguousarray(image), light


def light_colour(bgr: np.ndarray) -> FrameLight | None:
    """The light of a colour frame where it is one colour (a laser: :data:`ONE_COLOUR_RATIO`,
    :data:`ONE_COLOUR_SHARE`), else None (lights of several colours, or fewer than
    :data:`BRIGHT_MIN_PX` bright pixels).

    ``bgr``: ``(H, W, 3)`` uint8 or uint16. The light's colour is each channel's median over the
    bright pixels (:data:`BRIGHT_FRACTION`) less its background."""
    return _one_colour(bgr, _brightest(bgr))


def _brightest(bgr: np.ndarray) -> np.ndarray:
    """``(H, W)``: the brightest channel of each pixel (``bgr.max(axis=2)``, in OpenCV: a third
    of numpy's time on a strided colour frame)."""
    return np.asarray(cv2.max(cv2.max(bgr[:, :, 0], bgr[:, :, 1]), bgr[:, :, 2]))


def _one_colour(bgr: np.ndarray, brightest: np.ndarray) -> FrameLight | None:
    """:func:`light_colour` of ``bgr`` with its brightest channel of each pixel given."""
    top = np.iinfo(bgr.dtype).max
    background = np.median(bgr.reshape(-1, 3)[::97], axis=0).astype(np.float64)
    high = float(np.percentile(brightest.ravel()[::7], 99.9))
    base = float(background.max())
    if not high > base:
        return None
    bright = (brightest > base + BRIGHT_FRACTION * (high - base)) & (brightest < top)
    if int(np.count_nonzero(bright)) < BRIGHT_MIN_PX:
        return None
    values = bgr[bright].astype(np.float64) - background  # (P, 3)
    light = np.median(values, axis=0)
    strongest = int(np.argmax(light))
    others = np.max(np.delete(values, strongest, axis=1), axis=1)
    own = values[:, strongest]
    if not (
        np.median(own - ONE_COLOUR_RATIO * others) > 0
        and np.quantile(own - others, 1.0 - ONE_COLOUR_SHARE) > 0
    ):
        return None
    return FrameLight(light / light[strongest], background)


def _luma_of(bgr: np.ndarray, light: FrameLight) -> np.ndarray:
    """``(H, W)`` in ``bgr``'s dtype: the luma (:data:`LUMA_BGR`) of the light above the
    background over the luma of its colour, plus the strongest channel's background, so that
    the light's strongest channel keeps its values; rounded, and clipped at the dtype's
    maximum (where that channel saturates, this passes the maximum too: the frame's clip)."""
    weights = np.asarray(LUMA_BGR, np.float64)
    scale = weights / float(weights @ light.colour_bgr)
    strongest = int(np.argmax(light.colour_bgr))
    offset = float(light.background_bgr[strongest] - scale @ light.background_bgr)
    out = cv2.transform(np.ascontiguousarray(bgr), np.append(scale, offset).reshape(1, 4))
    return out.reshape(bgr.shape[:2])


def _weighted_median(values: np.ndarray, counts: np.ndarray) -> float:
    """``np.median`` of a sample given as distinct ``values`` (ascending) and their counts:
    the middle order statistic, or the mean of the two middle ones."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    lo = values[np.searchsorted(cum, (n - 1) // 2, side="right")]
    hi = values[np.searchsorted(cum, n // 2, side="right")]
    return 0.5 * (float(lo) + float(hi))


def background_and_noise(gray: np.ndarray) -> tuple[float, float]:
    """Robust background level (median) and noise sigma (scaled MAD) of a sparse-dot frame,
    in the frame's own units.

    Uses a regular sub-sample, so that the cost does not grow with the frame. Dots cover a
    small fraction of a laser-grid frame, so both statistics see the background. 8-bit frames
    take the same statistics from the sample's histogram (exact, and faster than sorting).
    """
    step = max(1, int(np.sqrt(gray.size / 12000)))
    sample = gray[::step, ::step].ravel()
    if gray.dtype == np.uint8:
        counts = np.bincount(sample, minlength=256)
        values = np.arange(256, dtype=np.float64)
        median = _weighted_median(values, counts)
        dist = np.abs(values - median)
        order = np.argsort(dist, kind="stable")
        sigma0 = max(1.4826 * _weighted_median(dist[order], counts[order]), 0.5)
        w = np.where(dist <= 4.0 * sigma0 + 1.0, counts, 0).astype(np.float64)
        background = float(w @ values / w.sum())
        noise = float(np.sqrt(w @ (values - background) ** 2 / w.sum()))
        return background, noise
    sample = sample.astype(np.float64)
    median = float(np.median(sample))
    sigma0 = max(1.4826 * float(np.median(np.abs(sample - median))), 0.5)
    # The median of integer-valued data is off by up to half a step, which the integrals
    # along streaks would amplify: take the mean of the central part instead.
    core = sample[np.abs(sample - median) <= 4.0 * sigma0 + 1.0]
    background = float(np.mean(core))
    noise = float(np.std(core))
    return background, noise


def background_levels(
    gray: np.ndarray, noise: float, block: int = BACKGROUND_BLOCK_PX
) -> np.ndarray:
    """Background level per block of ``block`` px, ``(by, bx)`` float32 (frame units): the
    mean of a sparse sample within ``4 noise + 1`` of the block's median (dots cover a small
    part of a block; the trimmed mean avoids the half-step bias of medians of integer data),
    then a 3x3 median over blocks (a block crowded by a streak takes its neighbours' level)."""
    step = max(block // 8, 1)
    k = block // step
    sub = gray[::step, ::step]
    by, bx = max(sub.shape[0] // k, 1), max(sub.shape[1] // k, 1)
    kh, kw = min(k, sub.shape[0]), min(k, sub.shape[1])
    smp: np.ndarray = sub[: by * kh, : bx * kw].reshape(by, kh, bx, kw).transpose(0, 2, 1, 3)
    smp = smp.reshape(by, bx, kh * kw)
    med = np.median(smp, axis=2, keepdims=True).astype(np.float32)  # on the integers: faster
    smp = smp.astype(np.float32)
    keep = np.abs(smp - med) <= 4.0 * noise + 1.0
    level = (smp * keep).sum(axis=2) / np.maximum(keep.sum(axis=2), 1)
    if by >= 3 and bx >= 3:
        level = cv2.medianBlur(level.astype(np.float32), 3)
    return level.astype(np.float32)


def sparse_points(mask: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices ``(K,)`` of the nonzero pixels of a uint8 mask, in raster order,
    given their ``count``. A sparse contiguous mask is scanned as 64-bit words (numpy finds
    the few nonzero words about twice as fast as ``cv2.findNonZero`` scans the bytes);
    otherwise ``cv2.findNonZero``."""
    flat = mask.reshape(-1) if mask.flags.c_contiguous else None
    if flat is None or flat.size % 8 or count > flat.size // 200:
        nz = cv2.findNonZero(mask)
        nz = np.zeros((0, 2), np.int64) if nz is None else nz.reshape(-1, 2).astype(np.int64)
        return nz[:, 1], nz[:, 0]
    words = np.flatnonzero(flat.view(np.uint64))
    idx = (words[:, None] * 8 + np.arange(8)).ravel()
    idx = idx[flat[idx] != 0]
    return idx // mask.shape[1], idx % mask.shape[1]


def remove_hot_pixels(
    raw: np.ndarray, signal: np.ndarray, ratio: float, floor: float, raw_floor: float | None = None
) -> int:
    """Replace isolated hot pixels of ``signal`` in place; return how many were replaced.

    A hot pixel (not on the frame border) is a local maximum of ``raw`` (at least as bright as
    its 8 neighbours), exceeds ``floor`` (in ``signal`` units) and is more than ``ratio`` times
    brighter than its brightest 8-neighbour in ``signal``; it is replaced by that neighbour. A
    real dot (sigma >= ~0.7 px) always has a neighbour at more than a third of its peak, so it
    never qualifies. The candidate mask (local maximum and above the floor) is built with
    full-frame OpenCV operations, which are several times faster than numpy on a large frame
    and leave only a few candidates (dot peaks, hot pixels) for the exact ring test.

    ``raw_floor``: a raw value that every pixel above ``floor`` exceeds (``floor`` in raw units
    plus the lowest background, less a rounding margin); the floor is then pre-tested on the
    (smaller) raw frame and checked exactly on the candidates only. On a noise-free flat
    background every pixel is a local maximum, so the floor must come first.
    """
    cand = cv2.compare(raw, cv2.dilate(raw, _BOX), cv2.CMP_GE)
    if raw_floor is None or raw_floor < 0:
        above = cv2.compare(signal, float(floor), cv2.CMP_GT)  # type: ignore[call-overload]  # cv2 stubs lack the scalar src2
    else:  # integer data: raw > x exactly when raw > floor(x) (OpenCV rounds the scalar)
        above = cv2.compare(raw, float(np.floor(raw_floor)), cv2.CMP_GT)  # type: ignore[call-overload]  # cv2 stubs lack the scalar src2
    cv2.bitwise_and(cand, above, dst=cand)
    cand[0, :] = 0
    cand[-1, :] = 0
    cand[:, 0] = 0
    cand[:, -1] = 0
    count = cv2.countNonZero(cand)
    if count == 0:
        return 0
    ys, xs = sparse_points(cand, count)
    value = signal[ys, xs]
    bright = value > floor
    xs, ys, value = xs[bright], ys[bright], value[bright]
    ring = np.max(signal[ys[:, None] + _DY[None, :], xs[:, None] + _DX[None, :]], axis=1)
    hot = value > ratio * np.maximum(ring, 0.0)
    count = int(np.count_nonzero(hot))
    if count:
        signal[ys[hot], xs[hot]] = ring[hot]
    return count


def prepare_frame(
    image: np.ndarray,
    smooth_sigma_px: float,
    hot_pixel_ratio: float,
    saturation_level: float | None = None,
    colour: str = "auto",
) -> PreparedFrame:
    """Convert (``colour``: :func:`to_gray`), subtract the background, remove hot pixels and
    pre-smooth a frame."""
    raw, light = _gray_and_light(image, colour)
    top = float(np.iinfo(raw.dtype).max)
    level = top if saturation_level is None else float(saturation_level)
    saturated = raw >= level if raw.max() >= level else np.zeros((1, 1), bool)
    bg_raw, noise_raw = background_and_noise(raw)
    background, noise = bg_raw / top, max(noise_raw / top, 1e-4)
    bg_level = background_levels(raw, noise_raw)
    bg_map = cv2.resize(bg_level, (raw.shape[1], raw.shape[0]), interpolation=cv2.INTER_LINEAR)
    # (raw - background) / top in one OpenCV pass (float32 out).
    signal = cv2.addWeighted(raw, 1.0 / top, bg_map, -1.0 / top, 0.0, dtype=cv2.CV_32F)
    floor = 5.0 * noise
    # Bilinear upsampling stays within the block levels: their minimum bounds the map's (the
    # margin covers float32 rounding of the signal, far below 0.01 raw units).
    hot = remove_hot_pixels(
        raw, signal, hot_pixel_ratio, floor, floor * top + float(bg_level.min()) - 0.01
    )
    k = 2 * int(np.ceil(3.0 * smooth_sigma_px)) + 1  # +-3 sigma (OpenCV's float default: 4)
    smooth = cv2.GaussianBlur(signal, (k, k), smooth_sigma_px, borderType=cv2.BORDER_REPLICATE)
    # Noise of white noise after a Gaussian blur of sigma s: sigma / (2 sqrt(pi) s).
    noise_smooth = noise / (2.0 * np.sqrt(np.pi) * smooth_sigma_px)
    return PreparedFrame(
        signal=signal,
        smooth=smooth,
        saturated=saturated,
        background=background,
        noise=noise,
        noise_smooth=float(noise_smooth),
        saturation=level / top - background,
        hot_pixels=hot,
        light_bgr=None
        if light is None
        else (
            float(light.colour_bgr[0]),
            float(light.colour_bgr[1]),
            float(light.colour_bgr[2]),
        ),
    )
