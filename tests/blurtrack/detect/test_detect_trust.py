"""Point light or extended source, and the precision-first ``quality_ok`` (issue 45), on
synthetic frames: point streaks rendered analytically (:mod:`blurtrack.testing.streak_frames`)
beside extended sources drawn with OpenCV (a lit window, a screen, sign-like strokes several
times the dot's width), blurred by the same PSF."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.params import SourceParams
from blurtrack.detect.separation.quality import REASONS, frame_quality
from blurtrack.detect.trust import Evidence, min_contrast
from blurtrack.errors import ConfigError, DetectionError
from blurtrack.testing.streak_frames import line_grid, quantise, render_streaks

SHAPE = (240, 320)
SIGMA = 1.5  # the dots' spread (px)
#: The extended sources' boxes (x0, y0, x1, y1): window, screen, sign strokes.
WINDOW = (20, 20, 60, 50)
SCREEN = (90, 15, 150, 55)
SIGN = (180, 10, 310, 70)


def _points() -> list[np.ndarray]:
    """Twelve dots' streaks, all drawing the same 18 px curve, in the lower half."""
    return line_grid(12, 6, (25.0, 120.0), (48.0, 50.0), (16.0, 8.0))


def _extended(level: float) -> np.ndarray:
    """A lit window, a dimmer screen and text-like strokes (thickness 5 px, ~3.3 dot
    sigmas), blurred by the dots' PSF: float image in full-scale units."""
    layer = np.zeros(SHAPE, np.uint8)  # OpenCV draws text on 8-bit images only
    x0, y0, x1, y1 = WINDOW
    cv2.rectangle(layer, (x0, y0), (x1, y1), 200, -1)
    x0, y0, x1, y1 = SCREEN
    cv2.rectangle(layer, (x0, y0), (x1, y1), 100, -1)
    cv2.putText(layer, "BAR", (SIGN[0], SIGN[3] - 12), cv2.FONT_HERSHEY_SIMPLEX, 1.6, 200, 5)
    lit = layer.astype(np.float32) * np.float32(level / 200.0)
    return cv2.GaussianBlur(lit, (0, 0), SIGMA).astype(np.float64)


def _frame(points: bool = True, extended: bool = True, seed: int = 0) -> np.ndarray:
    curves = _points() if points else []
    img = render_streaks(SHAPE, curves, 2.0, SIGMA, 0.03, 0.004, seed)
    if extended:
        img = img + _extended(0.6)
    return img


def _in_box(fs: FrameStreaks, box: tuple[int, int, int, int], pad: float = 6.0) -> np.ndarray:
    x0, y0, x1, y1 = box
    m = fs.time_mid
    return (m[:, 0] > x0 - pad) & (m[:, 0] < x1 + pad) & (m[:, 1] > y0 - pad) & (m[:, 1] < y1 + pad)


def _columns(fs: FrameStreaks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``quality_ok``, ``source`` and ``reason`` of a frame's streaks."""
    (_, _, ok, source, reason), _ = frame_quality(fs)
    return ok, source, reason


def _check(fs: FrameStreaks) -> None:
    ok, source, reason = _columns(fs)
    ext = _in_box(fs, WINDOW) | _in_box(fs, SCREEN) | _in_box(fs, SIGN)
    assert ext.sum() >= 3  # every extended source was detected as something
    # Never a point light, never quality_ok; most of them measured extended (a few pieces of
    # the strokes, cut where the letters meet, stay undetermined).
    assert not np.any(source[ext] == "point"), list(zip(source[ext], reason[ext], strict=True))
    assert np.mean(source[ext] == "extended") >= 0.7
    assert not ok[ext].any()
    # Negative control: the dots stay point lights and quality_ok.
    pts = ~ext
    assert pts.sum() == 12
    assert np.all(source[pts] == "point") and ok[pts].all()
    assert set(reason) <= set(REASONS)


def test_extended_sources_are_extended_and_the_dots_stay_points() -> None:
    _check(detect_frame(quantise(_frame(), np.uint8)))


@pytest.mark.parametrize("kind", ["uint16", "bgr"])
def test_sixteen_bit_and_colour_frames_give_the_same_sources(kind: str) -> None:
    if kind == "uint16":
        img = quantise(_frame(), np.uint16)
    else:
        gray = quantise(_frame(), np.uint8)
        img = np.dstack([gray // 3, gray, gray // 2])  # the brightest channel carries it
    _check(detect_frame(img))


def test_a_frame_of_extended_light_only_has_no_ok_streak() -> None:
    img = quantise(_frame(points=False), np.uint8)
    fs = detect_frame(img)
    ok, _, _ = _columns(fs)
    assert len(fs) >= 3 and not ok.any()
    # Without a dot the frame's own spread is the strokes' (a known limit): with the optics'
    # spread given, none is a point light either.
    fs = detect_frame(img, DetectParams(psf_sigma_px=SIGMA))
    ok, source, _ = _columns(fs)
    assert not ok.any() and not np.any(source == "point")


def test_an_all_saturated_frame_has_no_ok_streak() -> None:
    for img in (np.full(SHAPE, 255, np.uint8), np.full(SHAPE, 65535, np.uint16)):
        fs = detect_frame(img)
        ok, _, _ = _columns(fs)
        assert not ok.any()
    # A frame whose lights are all blown out far wider than a dot: none ok either.
    fs = detect_frame(quantise(3.0 * _frame(points=False), np.uint8))
    ok, source, _ = _columns(fs)
    assert not ok.any() and not np.any(source == "point")


def test_source_parameters_are_validated_and_read_from_yaml() -> None:
    p = DetectParams.from_dict({"source": {"extended_fill": 4.0}})
    assert p.source == SourceParams(extended_fill=4.0)
    assert DetectParams.from_dict(p.to_dict()) == p
    with pytest.raises(ConfigError):
        DetectParams.from_dict({"source": {"bogus": 1.0}})
    with pytest.raises(ConfigError):
        SourceParams(point_fill=5.0, extended_fill=3.0)


def test_min_contrast_is_where_a_wider_source_first_fills_more_than_a_point() -> None:
    p = SourceParams()
    r, f = p.extended_width_ratio, p.point_fill
    L = np.log(min_contrast(p))
    assert min_contrast(p) == pytest.approx(2.44, abs=0.01)
    # At that contrast a source r times the PSF wide lights exactly f times a point's band;
    # brighter, more (the fill then tells them apart); fainter, less.
    assert r * np.sqrt(L / (L + np.log(r))) == pytest.approx(f)
    assert r * np.sqrt(1.2 * L / (1.2 * L + np.log(r))) > f
    assert r * np.sqrt(0.8 * L / (0.8 * L + np.log(r))) < f
    assert min_contrast(SourceParams(point_fill=2.0, extended_fill=3.0)) == float("inf")


@pytest.mark.parametrize(("flux", "point"), [(0.07, False), (0.6, True)])
def test_a_streak_near_the_threshold_is_not_called_a_point_light(flux, point) -> None:
    # The twelve dots at a peak of ~1.6x the segmentation threshold: their lit band is the
    # core of whatever drew them, so nothing says point (nor quality_ok); brighter (the
    # negative control, ~13x), they are point lights again.
    img = render_streaks(SHAPE, _points(), flux, SIGMA, 0.03, 0.004, 1)
    fs = detect_frame(quantise(img, np.uint16), DetectParams(psf_sigma_px=SIGMA))
    ok, source, _ = _columns(fs)
    assert len(fs) == 12 and fs.evidence is not None
    c = fs.evidence.contrast
    if point:
        assert np.all(c > 2.0 * min_contrast(SourceParams()))
        assert np.all(source == "point") and ok.all()
    else:
        assert np.all(c < min_contrast(SourceParams())) and np.all(c > 1.0)
        assert not np.any(source == "point") and not ok.any()


def test_evidence_split_and_joined_again_is_the_same() -> None:
    img = render_streaks(SHAPE, _points(), 0.6, SIGMA, 0.03, 0.004, 1)
    ev = detect_frame(quantise(img, np.uint16), DetectParams(psf_sigma_px=SIGMA)).evidence
    assert ev is not None and len(ev) == 12
    rows = np.arange(len(ev))
    joined = Evidence.concat([ev.take(rows[:5]), ev.take(rows[5:])])
    for f in dataclasses.fields(Evidence):
        np.testing.assert_array_equal(getattr(joined, f.name), getattr(ev, f.name))
    # the other way round, the rows come back swapped
    swapped = Evidence.concat([ev.take(rows[5:]), ev.take(rows[:5])])
    np.testing.assert_array_equal(swapped.fill, np.concatenate([ev.fill[5:], ev.fill[:5]]))
    assert len(Evidence.concat([])) == 0


def test_expected_area_and_end_frames_are_those_of_each_streak_alone() -> None:
    """The batched forms give, streak by streak, the values of the formulas applied to each
    streak alone (profiles of any length, empty ones too; lines of one to many points)."""
    from blurtrack.detect.trust import TANGENT_POINTS, _end_frames, _expected_area

    rng = np.random.default_rng(3)
    psf, threshold = 1.3, 0.05
    profiles = [rng.uniform(0, 2, int(rng.integers(0, 60))) for _ in range(50)]
    norm = np.sqrt(2.0 * np.pi) * psf
    for pr, got in zip(profiles, _expected_area(profiles, psf, threshold), strict=True):
        h = psf * np.sqrt(2.0 * np.log(np.maximum(pr / norm / threshold, 1.0)))
        caps = np.pi * (h[0] ** 2 + h[-1] ** 2) / 2.0 if h.size else 0.0
        assert got == 2.0 * h.sum() + caps
    assert _expected_area([], psf, threshold).shape == (0,)
    lines = [np.cumsum(rng.normal(0, 1, (int(rng.integers(1, 12)), 2)), axis=0) for _ in range(40)]
    ends, tang = _end_frames(lines)
    raw = np.zeros_like(tang)  # each line's own ends and tangents, then normalised alike
    for i, p in enumerate(lines):
        np.testing.assert_array_equal(ends[i], [p[0], p[-1]])
        k = min(TANGENT_POINTS, len(p) - 1)
        if k >= 1:
            raw[i] = [p[0] - p[k], p[-1] - p[-1 - k]]
    nrm = np.linalg.norm(raw, axis=2, keepdims=True)
    np.testing.assert_array_equal(
        tang, np.where(nrm > 1e-9, raw / np.maximum(nrm, 1e-9), [1.0, 0.0])
    )
    assert np.allclose(np.linalg.norm(tang, axis=2), 1.0)
    one = [len(p) == 1 for p in lines]
    assert any(one) and np.all(tang[one] == [1.0, 0.0])  # one point: the convention (1, 0)
    with pytest.raises(DetectionError, match="no points"):
        _end_frames([np.zeros((3, 2)), np.zeros((0, 2))])
