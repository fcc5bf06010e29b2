"""Colour frames to one channel (``blurtrack.detect.image.to_gray``, ``light_colour``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.image import LUMA_BGR, light_colour, to_gray
from blurtrack.errors import ConfigError, DetectionError
from blurtrack.testing.streak_frames import line, render_streaks

SHAPE = (160, 240)
LASER = (0.06, 0.18, 1.0)  # B, G, R: a red laser seen through an RGB colour filter array


def _curves(seed: int) -> list[np.ndarray]:
    """Twelve straight streaks of 15-30 px in a 4 x 3 grid."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(12):
        p0 = np.array([30.0 + 60 * (k % 4), 30.0 + 50 * (k // 4)]) + rng.uniform(-4, 4, 2)
        ang = rng.uniform(0, 2 * np.pi)
        out.append(line(p0, p0 + rng.uniform(15, 30) * np.array([np.cos(ang), np.sin(ang)])))
    return out


def _bgr(
    curves: list[np.ndarray],
    colours: list[tuple[float, float, float]],
    flux: float = 2.0,
    noise: float = 0.004,
    seed: int = 0,
) -> np.ndarray:
    """8-bit BGR frame: streak k in ``colours[k % len(colours)]`` over a grey background,
    independent noise per channel, clipped at white."""
    rng = np.random.default_rng(seed)
    channels = np.full((*SHAPE, 3), 0.03)
    for k, c in enumerate(curves):
        light = render_streaks(SHAPE, [c], flux, 1.3, 0.0, 0.0, seed)
        channels += light[:, :, None] * np.asarray(colours[k % len(colours)])[None, None, :]
    channels += rng.normal(0.0, noise, channels.shape)
    return np.asarray(np.rint(np.clip(channels, 0.0, 1.0) * 255), np.uint8)


def _median_end_error(fs, curves: list[np.ndarray]) -> float:
    """Median over the true streaks of the mean distance of the nearest detection's two ends
    (either orientation)."""
    errors = []
    for c in curves:
        d0 = np.linalg.norm(fs.end_a - c[0], axis=1) + np.linalg.norm(fs.end_b - c[-1], axis=1)
        d1 = np.linalg.norm(fs.end_a - c[-1], axis=1) + np.linalg.norm(fs.end_b - c[0], axis=1)
        errors.append(float(np.min(np.minimum(d0, d1))) / 2)
    return float(np.median(errors))


def test_a_lasers_light_is_one_colour_white_or_mixed_light_is_not() -> None:
    curves = _curves(0)
    light = light_colour(_bgr(curves, [LASER]))
    assert light is not None
    np.testing.assert_allclose(light.colour_bgr, LASER, atol=0.03)
    np.testing.assert_allclose(light.background_bgr, 0.03 * 255, atol=1.0)
    # Negative controls: white lights, and lights of two colours (red and green).
    assert light_colour(_bgr(curves, [(1.0, 1.0, 1.0)])) is None
    assert light_colour(_bgr(curves, [LASER, (0.1, 1.0, 0.1)])) is None
    # A warm light (red over green 1.5) is not a laser's one colour either.
    assert light_colour(_bgr(curves, [(0.4, 0.67, 1.0)])) is None
    # Too few bright pixels to tell: one short faint dot.
    assert light_colour(_bgr([line((50, 50), (52, 50))], [LASER], flux=0.3)) is None


def test_auto_keeps_the_lasers_channel_and_clips_where_that_channel_saturates() -> None:
    img = _bgr(_curves(1), [LASER], flux=6.0, noise=0.0)  # cores far above white in red
    red = img[:, :, 2].astype(int)
    gray = to_gray(img, "auto").astype(int)
    assert gray.shape == SHAPE
    assert not np.array_equal(gray, img.max(axis=2))  # the light's luma, not the brightest
    unsat = (red < 250) & (red > 20)
    # The luma of the light above the background over its colour's luma, on the red
    # channel's background: the red channel's values, to the rounding of the three channels.
    assert np.max(np.abs(gray[unsat] - red[unsat])) <= 2
    clipped = red == 255
    assert clipped.sum() > 100
    assert np.all(gray[clipped] >= 253)  # saturated where red is, as a hard clip
    assert np.all(gray[clipped & (img[:, :, 1] > 60)] == 255)  # deep in the cores
    # ``max`` is the brightest channel of each pixel, as before.
    np.testing.assert_array_equal(to_gray(img, "max"), img.max(axis=2))
    # Where the light is not one colour, ``auto`` is ``max`` too.
    white = _bgr(_curves(1), [(1.0, 1.0, 1.0)])
    np.testing.assert_array_equal(to_gray(white, "auto"), white.max(axis=2))
    # The luma weights are BT.601's.
    assert LUMA_BGR == (0.114, 0.587, 0.299)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_red_laser_in_a_chroma_subsampled_jpeg_is_measured_on_luma(seed: int) -> None:
    """JPEG keeps luma at full resolution and the colour differences at half (4:2:0,
    OpenCV's default): a red laser's red channel is mostly colour difference, so its ends
    blur; the brightest channel (``max``) is the negative control."""
    curves = _curves(seed)
    ok, encoded = cv2.imencode(
        ".jpg", _bgr(curves, [LASER], seed=seed), [cv2.IMWRITE_JPEG_QUALITY, 85]
    )
    assert ok
    jpeg = cv2.imdecode(encoded, cv2.IMREAD_UNCHANGED)
    auto = detect_frame(jpeg, DetectParams(colour="auto"))
    brightest = detect_frame(jpeg, DetectParams(colour="max"))
    assert auto.light_bgr is not None and auto.light_bgr[2] == 1.0  # red, the strongest
    assert brightest.light_bgr is None
    e_auto, e_max = _median_end_error(auto, curves), _median_end_error(brightest, curves)
    assert e_auto < 0.3
    assert e_max > 2 * e_auto


def test_colour_mode_is_checked() -> None:
    with pytest.raises(ConfigError, match="colour"):
        DetectParams(colour="luma")
    with pytest.raises(DetectionError, match="colour"):
        to_gray(np.zeros((20, 20, 3), np.uint8), "red")
    assert DetectParams.from_dict({"colour": "max"}).colour == "max"
