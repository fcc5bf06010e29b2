"""The flat top of a streak's cross-section (:mod:`blurtrack.detect.flattop`): known values of
the box-blurred curve, measured widths of rendered bands against their own edges, and frames of
lit bars only, where the frame's own spread is the bars' and every width against it says
"point" (issue 45: signs and lit bars drawn as point lights)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.special import erf

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.context import frame_context
from blurtrack.detect.flattop import (
    POINT_RATIO,
    STEP_PX,
    frame_own_width_ratio,
    near_saturation,
    own_ratio_of_profiles,
    own_width_ratio,
    width_ratio_of,
)
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.params import SourceParams
from blurtrack.detect.separation.quality import frame_quality
from blurtrack.detect.trust import classify_source, min_contrast
from blurtrack.testing.streak_frames import line, quantise, render_streaks

SIGMA = 1.5  # the optics' spread (px)
SHAPE = (240, 320)
#: Separate lit bars (x0, y0, x1, y1): strokes of a sign, none touching another.
BARS = [
    (30, 40, 30, 150),
    (80, 40, 120, 150),
    (160, 40, 290, 40),
    (160, 110, 290, 110),
    (160, 190, 290, 215),
    (30, 200, 110, 200),
]


def _band(half_px: float, sigma: float, x: np.ndarray) -> np.ndarray:
    """A box of half-width ``half_px`` blurred by a Gaussian of ``sigma`` (a Gaussian for 0)."""
    if half_px == 0:
        return np.exp(-0.5 * (x / sigma) ** 2)
    s = sigma * np.sqrt(2.0)
    return 0.5 * (erf((x + half_px) / s) - erf((x - half_px) / s))


def _w90_w50(v: np.ndarray, x: np.ndarray) -> float:
    """W90 / W50 of a symmetric single-peaked profile on a fine grid."""

    def width(level: float) -> float:
        above = x[v >= level * v.max()]
        return float(above.max() - above.min())

    return width(0.9) / width(0.5)


def test_the_point_ratio_is_a_gaussians_whatever_its_sigma() -> None:
    x = np.linspace(-30, 30, 60001)
    for sigma in (0.8, 1.5, 4.0):
        assert _w90_w50(_band(0.0, sigma, x), x) == pytest.approx(POINT_RATIO, abs=2e-3)
    assert width_ratio_of(np.array([POINT_RATIO]))[0] == pytest.approx(1.0, abs=0.02)
    assert width_ratio_of(np.array([0.2]))[0] == pytest.approx(1.0)  # rounder than a Gaussian
    assert np.isnan(width_ratio_of(np.array([np.nan]))[0])


@pytest.mark.parametrize("b_sigmas", [2.0, 3.0, 4.0, 6.0])
def test_a_blurred_box_measures_its_rms_width_over_its_edges(b_sigmas: float) -> None:
    # Truth: the rms width of a box of half-width b blurred by sigma, over sigma.
    x = np.linspace(-40, 40, 80001)
    ratio = _w90_w50(_band(b_sigmas * 1.3, 1.3, x), x)
    want = np.sqrt(1.0 + b_sigmas**2 / 3.0)
    assert width_ratio_of(np.array([ratio]))[0] == pytest.approx(want, rel=0.02)


def _image(
    curves: list[np.ndarray], bars: list[tuple[int, int, int, int]], thick: int, level: float
) -> np.ndarray:
    """Point streaks of ``curves`` and lit bars ``thick`` px wide at ``level`` (full scale),
    all blurred by the same PSF; float image."""
    img = render_streaks(SHAPE, curves, 2.0, SIGMA, 0.03, 0.004, 0)
    layer = np.zeros(SHAPE, np.uint8)
    for x0, y0, x1, y1 in bars:
        cv2.line(layer, (x0, y0), (x1, y1), 200, thick)
    lit = cv2.GaussianBlur(layer.astype(np.float32) * np.float32(level / 200.0), (0, 0), SIGMA)
    return img + lit


def _smooth(img: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)


def test_a_point_streak_measures_one_and_a_lit_bar_its_width() -> None:
    dot = line([40.0, 60.0], [200.0, 90.0])
    img = _image([dot], [(40, 170, 280, 170)], 16, 0.6)
    smooth = _smooth(img)
    pts = [line([50.0, 62.0], [190.0, 88.0], 141), line([60.0, 170.0], [260.0, 170.0], 201)]
    own = own_width_ratio(smooth, None, pts, 1.8)
    assert own[0] < 1.2
    # A 16 px bar: b = 8 px against the edges' sigma sqrt(1.5^2 + 1^2) (optics and smoothing).
    sig = np.hypot(SIGMA, 1.0)
    assert own[1] == pytest.approx(np.sqrt(1.0 + (8.0 / sig) ** 2 / 3.0), rel=0.1)


def test_clipped_sections_give_no_evidence_and_short_lines_are_measured_round() -> None:
    img = _image([], [(40, 170, 280, 170)], 16, 3.0)  # blown out: a flat top whatever drew it
    signal = np.minimum(img, 1.0).astype(np.float32)
    near = near_saturation(signal, 1.0, 1.0)
    assert near is not None and near.max() == 1.0
    pts = [line([60.0, 170.0], [260.0, 170.0], 201)]
    assert np.isnan(own_width_ratio(_smooth(signal), near, pts, 1.8)[0])
    assert near_saturation(np.zeros(SHAPE, np.float32), 1.0, 1.0) is None
    # A spot (one centre-line point): sections through it in every direction.
    spot = render_streaks(SHAPE, [line([100.0, 100.0], [100.5, 100.0])], 2.0, SIGMA, 0.0)
    own = own_width_ratio(_smooth(spot), None, [np.array([[100.25, 100.0]])], 1.8)
    assert own[0] < 1.2


def test_a_laser_dot_frame_is_not_measured_again() -> None:
    curves = [
        line([20.0 + 45 * k, 40.0 + 40 * j], [36.0 + 45 * k, 50.0 + 40 * j])
        for k in range(6)
        for j in range(5)
    ]
    img = quantise(_image(curves, [], 1, 0.0), np.uint8)
    fs = detect_frame(img)
    p = DetectParams()
    prep = prepare_frame(img, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    ctx = frame_context(prep, p)
    got = frame_own_width_ratio(ctx, fs.points, fs.width_px, fs.sigma_c_px)
    assert len(fs) == 30 and np.isnan(got.ratio).all() and not got.psf_extended


def test_two_dots_half_a_psf_apart_measure_as_one_and_two_psfs_apart_as_extended() -> None:
    # extended_width_ratio's definition: no dot, nor two dots half a PSF apart, measures that
    # wide; two dots (a hairpin's arms) two PSF sigmas apart, unresolved, are no point light's
    # streak; farther apart the line's light is one dot's (the brighter arm's top).
    x = np.arange(-30.0, 30.0 + 1e-9, STEP_PX)
    p = SourceParams()

    def pair(d: float, sigma: float = 1.8) -> float:
        v = np.exp(-0.5 * ((x - d * sigma / 2) / sigma) ** 2)
        v += np.exp(-0.5 * ((x + d * sigma / 2) / sigma) ** 2)
        return float(own_ratio_of_profiles(v[None])[0])

    assert pair(0.0) == pytest.approx(1.0, abs=0.02)
    assert pair(0.5) < p.point_width_ratio
    assert pair(2.2) > p.extended_width_ratio
    assert pair(4.0) == pytest.approx(1.0, abs=0.02)


def test_own_widths_widen_past_the_limit_and_veto_where_the_psf_is_extended() -> None:
    p = SourceParams()
    wr = np.ones(5)
    fill = np.ones(5)
    own = np.array([np.nan, 1.2, 1.8, 2.3, 2.7])
    got = classify_source(wr, fill, p, None, own)
    assert list(got) == ["point", "point", "point", "extended", "extended"]
    got = classify_source(wr, fill, p, None, own, psf_extended=True)
    assert list(got) == ["undetermined", "point", "undetermined", "extended", "extended"]
    assert list(classify_source(wr, fill, p)) == ["point"] * 5  # negative control


def test_where_no_width_is_measured_the_fill_decides() -> None:
    # Two blown-out arms of one hairpin have no width of their own (NaN): unmeasured, the
    # lit area decides point or extended; a NaN width otherwise leaves the source open.
    p = SourceParams()
    wr = np.full(3, np.nan)
    fill = np.array([1.0, 0.5 * (p.point_fill + p.extended_fill), 2.0 * p.extended_fill])
    contrast = np.full(3, 2.0 * min_contrast(p))
    got = classify_source(wr, fill, p, contrast, unmeasured=np.ones(3, bool))
    assert list(got) == ["point", "undetermined", "extended"]
    # ... and a faint one is still no point light
    faint = classify_source(wr, fill, p, 0.4 * contrast, unmeasured=np.ones(3, bool))
    assert list(faint) == ["undetermined", "undetermined", "extended"]
    # negative control: without the mask the missing width leaves all but the large light open
    assert list(classify_source(wr, fill, p, contrast)) == ["undetermined"] * 2 + ["extended"]


@pytest.mark.parametrize("thick", [12, 16])
def test_a_frame_of_lit_bars_has_no_point_light(thick: int) -> None:
    fs = detect_frame(quantise(_image([], BARS, thick, 0.6), np.uint8))
    (_, _, ok, source, _), _ = frame_quality(fs)
    assert len(fs) >= len(BARS)
    assert not np.any(source == "point"), source
    assert np.mean(source == "extended") >= 0.7
    assert not ok.any()


def test_no_streaks_single_points_and_unmeasured_widths_give_no_evidence() -> None:
    img = quantise(_image([], BARS, 16, 0.6), np.uint8)
    p = DetectParams()
    prep = prepare_frame(img, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    ctx = frame_context(prep, p)
    none = frame_own_width_ratio(ctx, [], np.zeros(0), 2.0)
    assert none.ratio.shape == (0,) and not none.psf_extended
    # A spot off the lit bars (background only), a spot on a bar's flat middle and a line
    # along a bar, their widths not measured (NaN): the background holds no light to
    # measure, the spot is as flat as the bar.
    pts = [
        np.array([[5.0, 5.0]]),
        np.array([[30.0, 95.0]]),
        line([160.0, 40.0], [290.0, 40.0], 131),
    ]
    got = frame_own_width_ratio(ctx, pts, np.full(3, np.nan), 2.0)
    assert got.ratio.shape == (3,)
    own = own_width_ratio(ctx.smooth, None, pts, 2.0, ctx.noise_smooth)
    assert np.isnan(own[0]) and np.isnan(got.ratio[0])
    assert own[1] > SourceParams().extended_width_ratio
    assert own[2] > SourceParams().extended_width_ratio
    assert np.isfinite(own_width_ratio(ctx.smooth, None, pts[:1], 2.0)[0])  # negative control
