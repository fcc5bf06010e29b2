"""Real-optics effects of the simulated camera: what a laser wall looks like through a cheap lens,
a colour sensor and a JPEG encoder.

Applied by :func:`rigs.sim.render.expose` around the sensor model, in this order (each one off
at its default):

1. **laser speckle** (dots' light only): the dots' electrons times a log-normal field of mean 1,
   contrast ``speckle_contrast`` (its standard deviation) and grain ``speckle_px`` (the sigma
   of the Gaussian that correlates it), new every frame (the speckle of a moving camera
   changes). A time-averaged speckle, not fully developed speckle.
2. **lens blur varying over the field**: an extra Gaussian blur of sigma
   ``lens_blur_px (r / r_corner)^2`` (sharp in the centre, softest in the corners), by
   interpolating per pixel between :data:`BLUR_LEVELS` uniformly blurred copies.
3. **chromatic fringes** (lateral chromatic aberration, colour sensors only): the red image
   magnified and the blue one shrunk about the centre by ``chromatic_px`` at the corner.
4. **Bayer mosaic** (``colour_response = (r, g, b)``, the sensor's response to the dots' light
   per channel; the ambient light is grey): each pixel keeps one channel, RGGB.
5. noise, full well and quantisation (the sensor model of :func:`~rigs.sim.render.expose`),
   with **blooming** before the clip: ``blooming`` of the charge above the full well spills up
   and down the column, exponentially over ``BLOOM_LENGTH_PX``.
6. **demosaicing** (OpenCV's bilinear Bayer to BGR): colour frames are stored ``(H, W, 3)``.
7. **JPEG** (8-bit only): encoded at ``jpeg_quality`` and decoded again.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rigs.sim.errors import SimError

#: Uniformly blurred copies between which the field-varying blur interpolates.
BLUR_LEVELS = 4
#: Decay length (px) of the charge that blooms along a column.
BLOOM_LENGTH_PX = 3.0


@dataclass(frozen=True)
class Optics:
    """Lens, colour sensor and encoder effects (all off by default); see the module text."""

    speckle_contrast: float = 0.0
    speckle_px: float = 1.5
    lens_blur_px: float = 0.0
    chromatic_px: float = 0.0
    colour_response: tuple[float, ...] = ()
    blooming: float = 0.0
    jpeg_quality: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.speckle_contrast <= 2.0:
            raise SimError("speckle_contrast must be in [0, 2]")
        if not 0.3 <= self.speckle_px <= 20.0:
            raise SimError("speckle_px must be in [0.3, 20]")
        if not 0.0 <= self.lens_blur_px <= 10.0:
            raise SimError("lens_blur_px must be in [0, 10]")
        if not 0.0 <= self.chromatic_px <= 10.0:
            raise SimError("chromatic_px must be in [0, 10]")
        if len(self.colour_response) not in (0, 3) or not all(
            0.0 <= c <= 1.0 for c in self.colour_response
        ):
            raise SimError("colour_response must be () or 3 values in [0, 1] (r, g, b)")
        if self.chromatic_px > 0 and not self.colour_response:
            raise SimError("chromatic_px needs a colour sensor (colour_response)")
        if not 0.0 <= self.blooming <= 1.0:
            raise SimError("blooming must be in [0, 1]")
        if not (self.jpeg_quality == 0 or 1 <= self.jpeg_quality <= 100):
            raise SimError("jpeg_quality must be 0 (off) or 1..100")

    @property
    def colour(self) -> bool:
        return len(self.colour_response) == 3


def _corner_radius2(h: int, w: int) -> np.ndarray:
    """``(r / r_corner)^2`` over the frame, ``(H, W)`` float32."""
    y = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / max((h - 1) / 2, 1)
    x = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / max((w - 1) / 2, 1)
    return (x[None, :] ** 2 * w**2 + y[:, None] ** 2 * h**2) / np.float32(w**2 + h**2)


def speckle(dots_e: np.ndarray, o: Optics, rng: np.random.Generator | None) -> np.ndarray:
    """The dots' electrons times a mean-1 log-normal speckle field (none without ``rng``)."""
    if o.speckle_contrast == 0 or rng is None:
        return dots_e
    g = rng.standard_normal(dots_e.shape, dtype=np.float32)
    g = np.asarray(cv2.GaussianBlur(g, (0, 0), o.speckle_px, borderType=cv2.BORDER_REFLECT))
    g /= max(float(g.std()), 1e-12)
    # A log-normal of standard deviation c: exp(s g - s^2 / 2) with s^2 = log(1 + c^2).
    s = float(np.sqrt(np.log1p(o.speckle_contrast**2)))
    return dots_e * np.exp(s * g - s * s / 2)


def field_blur(img: np.ndarray, o: Optics) -> np.ndarray:
    """Gaussian blur of sigma ``lens_blur_px (r / r_corner)^2``, interpolated between levels."""
    if o.lens_blur_px == 0:
        return img
    h, w = img.shape
    src = np.asarray(img, np.float32)
    levels = [src] + [
        cv2.GaussianBlur(src, (0, 0), o.lens_blur_px * k / (BLUR_LEVELS - 1))
        for k in range(1, BLUR_LEVELS)
    ]
    t = _corner_radius2(h, w) * (BLUR_LEVELS - 1)
    k = np.minimum(t.astype(np.int64), BLUR_LEVELS - 2)
    f = t - k
    out = np.zeros_like(src)
    for j in range(BLUR_LEVELS - 1):
        m = k == j
        out[m] = (1 - f[m]) * levels[j][m] + f[m] * levels[j + 1][m]
    return out


def _magnify(img: np.ndarray, scale: float) -> np.ndarray:
    """``img`` magnified by ``scale`` about the image centre (bilinear)."""
    h, w = img.shape
    cx, cy = (w - 1) / 2, (h - 1) / 2
    M = np.array([[scale, 0, cx * (1 - scale)], [0, scale, cy * (1 - scale)]], np.float64)
    return cv2.warpAffine(
        img, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )


def mosaic(dots_e: np.ndarray, ambient_e: np.ndarray | float, o: Optics) -> np.ndarray:
    """Electrons on an RGGB Bayer sensor ``(H, W)``: per channel the dots times the response
    (red magnified, blue shrunk by the chromatic aberration), plus grey ambient light."""
    h, w = dots_e.shape
    r_corner = float(np.hypot((w - 1) / 2, (h - 1) / 2))
    scale = o.chromatic_px / r_corner
    src = np.asarray(dots_e, np.float32)
    red = _magnify(src, 1 + scale) if scale else src
    blue = _magnify(src, 1 - scale) if scale else src
    r, g, b = o.colour_response
    out = np.empty((h, w), np.float32)
    out[0::2, 0::2] = r * red[0::2, 0::2]
    out[0::2, 1::2] = g * src[0::2, 1::2]
    out[1::2, 0::2] = g * src[1::2, 0::2]
    out[1::2, 1::2] = b * blue[1::2, 1::2]
    return out + np.asarray(ambient_e, np.float32)


def bloom(e: np.ndarray, full_well_e: float, o: Optics) -> np.ndarray:
    """Charge above the full well, ``blooming`` of it spilled along the columns."""
    if o.blooming == 0:
        return e
    excess = np.maximum(e - np.float32(full_well_e), 0)
    if not excess.any():
        return e
    d = np.arange(-int(6 * BLOOM_LENGTH_PX), int(6 * BLOOM_LENGTH_PX) + 1)
    kern = np.exp(-np.abs(d) / BLOOM_LENGTH_PX)
    kern[d == 0] = 0.0  # the pixel itself keeps its full well
    kern = (kern / kern.sum()).astype(np.float32).reshape(-1, 1)
    spill = cv2.filter2D(excess, -1, kern, borderType=cv2.BORDER_CONSTANT)
    return np.minimum(e, np.float32(full_well_e)) + np.float32(o.blooming) * spill


def demosaic_and_encode(dn: np.ndarray, o: Optics) -> np.ndarray:
    """Bayer DN -> BGR (bilinear demosaicing), then the JPEG round trip (8-bit)."""
    img = dn
    if o.colour:
        # OpenCV names Bayer patterns by the second row's first two pixels: RGGB is "BG".
        img = cv2.cvtColor(dn, cv2.COLOR_BayerBG2BGR)
    if o.jpeg_quality and img.dtype == np.uint8:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(o.jpeg_quality)])
        if not ok:
            raise SimError("JPEG encoding failed")
        decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        assert decoded is not None  # a buffer cv2.imencode just wrote decodes
        img = np.asarray(decoded)
    return img
