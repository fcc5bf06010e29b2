"""Detection of single frames against analytic synthetic streaks (known endpoints)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.errors import DetectionError
from blurtrack.testing.streak_frames import line, quantise, render_streaks

SHAPE = (100, 120)


def _frame(curves, flux=2.0, noise=0.004, seed=0, dtype=np.uint8, sigma=1.5):
    return quantise(render_streaks(SHAPE, curves, flux, sigma, 0.03, noise, seed), dtype)


def _match(fs, p0, p1):
    """Index of the streak matching truth (p0, p1) and the two endpoint errors (either
    orientation, since single frames are not oriented)."""
    d0 = np.linalg.norm(fs.end_a - p0, axis=1) + np.linalg.norm(fs.end_b - p1, axis=1)
    d1 = np.linalg.norm(fs.end_a - p1, axis=1) + np.linalg.norm(fs.end_b - p0, axis=1)
    i = int(np.argmin(np.minimum(d0, d1)))
    a, b = (fs.end_a[i], fs.end_b[i]) if d0[i] < d1[i] else (fs.end_b[i], fs.end_a[i])
    return i, float(np.linalg.norm(a - p0)), float(np.linalg.norm(b - p1))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_straight_streaks_subpixel_endpoints(seed: int) -> None:
    rng = np.random.default_rng(seed)
    curves = []
    for k in range(6):
        p0 = np.array([20.0 + 40 * (k % 3), 25.0 + 50 * (k // 3)]) + rng.uniform(-3, 3, 2)
        ang = rng.uniform(0, 2 * np.pi)
        length = rng.uniform(6, 18)
        curves.append(line(p0, p0 + length * np.array([np.cos(ang), np.sin(ang)])))
    fs = detect_frame(_frame(curves, seed=seed))
    assert len(fs) == len(curves)
    errors = []
    for c in curves:
        i, ea, eb = _match(fs, c[0], c[-1])
        errors += [ea, eb]
        true_len = float(np.linalg.norm(c[-1] - c[0]))
        assert fs.length_px[i] == pytest.approx(true_len, abs=0.8)
        assert not any(fs.flags[k][i] for k in fs.flags)
    assert np.median(errors) < 0.25
    assert max(errors) < 0.8


def test_accelerating_streak_profile_follows_speed() -> None:
    # Starts 3x faster than it ends: the slow end is brighter (brightness ~ 1 / speed).
    c = line((20, 50), (100, 50), accel=0.5)
    fs = detect_frame(_frame([c]))
    assert len(fs) == 1
    _, ea, eb = _match(fs, c[0], c[-1])
    assert ea < 0.5 and eb < 0.5
    prof = fs.profile[0] if fs.end_a[0][0] < 60 else fs.profile[0][::-1]
    n = len(prof)
    assert np.mean(prof[-n // 4 :]) > 2.0 * np.mean(prof[: n // 4])
    # The time midpoint (half the light) lies on the slow side of the arc midpoint.
    assert fs.time_mid[0][0] > 62.0


@pytest.mark.parametrize("length", [12.0, 20.0])
def test_decelerating_streaks_have_unbiased_ends(length: float) -> None:
    # Speed falling from 1.4 to 0.6 times the mean (constant deceleration): the brightness
    # (1 / speed) is convex along the streak. A linear density model extrapolated to the ends
    # placed both outwards (+0.21 to +0.24 px per end on 12 px streaks, the short-streak fit;
    # +0.11 to +0.23 px on 20 px ones, the edge fit); the mean signed along-track error of
    # twelve streaks per length must stay near zero.
    rng = np.random.default_rng(7)
    curves = []
    for k in range(12):
        p0 = np.array([25.0 + 60 * (k % 6), 25.0 + 50 * (k // 6)]) + rng.uniform(-3, 3, 2)
        ang = rng.uniform(0, 2 * np.pi)
        curves.append(
            line(p0, p0 + length * np.array([np.cos(ang), np.sin(ang)]), n=800, accel=0.4)
        )
    img = quantise(render_streaks((130, 390), curves, 0.6, 1.3, 0.03, 0.004, 3))
    fs = detect_frame(img)
    out_start, out_end = [], []
    for c in curves:
        i, _, _ = _match(fs, c[0], c[-1])
        u = (c[-1] - c[0]) / length
        a, b = fs.end_a[i], fs.end_b[i]
        if np.linalg.norm(a - c[0]) > np.linalg.norm(b - c[0]):
            a, b = b, a
        out_start.append(-float(np.dot(a - c[0], u)))
        out_end.append(float(np.dot(b - c[-1], u)))
    assert abs(np.mean(out_start)) < 0.1 and abs(np.mean(out_end)) < 0.1


@pytest.mark.parametrize("length", [9.0, 14.0, 24.0])
def test_time_midpoints_of_decelerating_streaks(length: float) -> None:
    # Speed falling from 1.4 to 0.6 times the mean: the dot is at 60 % of the streak at
    # mid-exposure (1.2-2.4 px past the centre). The blurred profile's halving point between
    # the ends is pulled back towards the centre (by 0.2-0.35 px here before the correction,
    # :func:`blurtrack.detect.lines.centreline.blur_corrected_mid`); the mean signed error along
    # the streak of twelve streaks must stay under 0.05 px.
    rng = np.random.default_rng(11)
    curves = []
    for k in range(12):
        c0 = np.array([35.0 + 70 * (k % 5), 35.0 + 60 * (k // 5)]) + rng.uniform(-3, 3, 2)
        ang = rng.uniform(0, 2 * np.pi)
        d = length * np.array([np.cos(ang), np.sin(ang)])
        curves.append(line(c0 - d / 2, c0 + d / 2, n=801, accel=0.4))
    img = quantise(render_streaks((180, 380), curves, 0.6, 1.3, 0.03, 0.002, 4))
    fs = detect_frame(img)
    assert len(fs) == 12
    along, offset = [], []
    for c in curves:
        i, _, _ = _match(fs, c[0], c[-1])
        u = (c[-1] - c[0]) / length
        along.append(float(np.dot(fs.time_mid[i] - c[400], u)))
        offset.append(float(np.dot(c[400] - (c[0] + c[-1]) / 2, u)))
    assert np.mean(offset) > 0.09 * length
    assert abs(np.mean(along)) < 0.05, np.mean(along)


def test_round_static_dots_have_near_zero_length() -> None:
    # Several dots, so that the frame's dot width (which short streaks rely on) is well known.
    rng = np.random.default_rng(5)
    centres = [
        np.array([20.0 + 40 * (k % 3), 25.0 + 50 * (k // 3)]) + rng.uniform(-1, 1, 2)
        for k in range(6)
    ]
    # (Lengths of a few px are hard: they only widen the blur a little, L**2 / 12 against
    # sigma**2; hence a high signal-to-noise ratio here.)
    fs = detect_frame(_frame([np.stack([c, c]) for c in centres], noise=0.001))
    assert len(fs) == 6
    assert np.median(fs.length_px) < 1.0
    for c in centres:
        assert np.min(np.linalg.norm(fs.time_mid - c, axis=1)) < 0.5


def test_crossing_streaks_are_separated_and_flagged() -> None:
    c1, c2 = line((20, 20), (100, 80)), line((20, 80), (100, 20))
    fs = detect_frame(_frame([c1, c2]))
    assert len(fs) == 2
    assert fs.flags["crossing"].all()
    for c in (c1, c2):
        _, ea, eb = _match(fs, c[0], c[-1])
        assert ea < 0.5 and eb < 0.5


def test_s_curve_centre_line_and_ends() -> None:
    t = np.linspace(0, 1, 3000)
    s = np.stack([20 + 80 * t, 50 + 20 * np.sin(2 * np.pi * t)], axis=1)
    fs = detect_frame(_frame([s]))
    assert len(fs) == 1
    _, ea, eb = _match(fs, s[0], s[-1])
    assert ea < 0.5 and eb < 0.5
    assert cKDTree(s).query(fs.points[0])[0].max() < 0.5
    assert fs.length_px[0] == pytest.approx(
        np.sum(np.linalg.norm(np.diff(s, axis=0), axis=1)), rel=0.02
    )


def test_loop_is_one_streak_flagged_looped() -> None:
    th = np.linspace(0.6 * np.pi, 3.4 * np.pi, 3000)
    loop = np.stack([8 * th - 20 * np.sin(th) + 10, 50 - 20 * np.cos(th)], axis=1)
    fs = detect_frame(_frame([loop], flux=1.5))
    assert len(fs) == 1
    assert fs.flags["looped"][0]
    _, ea, eb = _match(fs, loop[0], loop[-1])
    assert ea < 0.6 and eb < 0.6
    # Away from the self-crossing the centre line is sub-pixel.
    assert np.median(cKDTree(loop).query(fs.points[0])[0]) < 0.3


def test_dot_entering_the_frame_is_clipped() -> None:
    c = line((-10, 40), (50, 60))
    fs = detect_frame(_frame([c]))
    assert len(fs) == 1
    assert fs.flags["clipped"][0]
    inside = fs.end_a[0] if fs.end_a[0][0] > fs.end_b[0][0] else fs.end_b[0]
    assert np.linalg.norm(inside - c[-1]) < 0.5


def test_saturated_core_endpoints_and_flag() -> None:
    c = line((20, 30), (90, 70))
    img = render_streaks(SHAPE, [c], 8.0, 1.5, 0.03, 0.004)
    assert img.max() > 1.5  # clipped by quantisation
    fs = detect_frame(quantise(img))
    assert len(fs) == 1 and fs.flags["saturated"][0]
    _, ea, eb = _match(fs, c[0], c[-1])
    assert ea < 0.4 and eb < 0.4


def test_low_contrast_streak_found_and_flagged_faint() -> None:
    c = line((20, 30), (90, 70))
    fs = detect_frame(_frame([c], flux=0.25, noise=0.01, seed=4))
    assert len(fs) == 1 and fs.flags["faint"][0]
    _, ea, eb = _match(fs, c[0], c[-1])
    assert ea < 2.0 and eb < 2.0  # noise-limited: the peak is ~6 noise sigmas


def test_hot_pixels_are_removed_not_detected() -> None:
    c = line((20, 30), (90, 70))
    img = _frame([c])
    img[10, 10] = 255
    img[80, 20] = 200
    img[50, 110] = 255
    fs = detect_frame(img)
    assert len(fs) == 1
    assert fs.hot_pixels == 3


def test_colour_and_16_bit_input_agree_with_gray() -> None:
    c = line((20, 30), (90, 70))
    img = render_streaks(SHAPE, [c], 2.0, 1.5, 0.03, 0.004)
    gray = detect_frame(quantise(img))
    deep = detect_frame(quantise(img, np.uint16))
    bgr = np.zeros((*SHAPE, 3), np.uint8)
    bgr[..., 2] = quantise(img)  # a red laser
    bgr[..., 1] = quantise(img) // 3
    colour = detect_frame(bgr)
    for fs in (deep, colour):
        assert len(fs) == 1
        ends = sorted([fs.end_a[0].tolist(), fs.end_b[0].tolist()])
        ref = sorted([gray.end_a[0].tolist(), gray.end_b[0].tolist()])
        assert np.allclose(ends, ref, atol=0.2)


def test_frame_without_dots_returns_no_streaks() -> None:
    fs = detect_frame(_frame([]))
    assert len(fs) == 0
    assert fs.end_a.shape == (0, 2)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((50, 60), np.float32), np.zeros((4, 4), np.uint8), np.zeros((20, 20, 2), np.uint8)],
)
def test_bad_frames_raise_detection_error(bad: np.ndarray) -> None:
    with pytest.raises(DetectionError):
        detect_frame(bad)


def test_too_many_components_is_an_error() -> None:
    img = np.zeros((100, 120), np.uint8)
    for y in range(5, 95, 8):
        for x in range(5, 115, 8):
            img[y : y + 3, x : x + 3] = 200  # 168 bright squares
    with pytest.raises(DetectionError, match="components"):
        detect_frame(img, DetectParams(max_streaks=20))


def test_streaks_touching_end_to_end_are_split() -> None:
    # Two collinear 30 px streaks 5 px apart (their masks join), among ordinary 30 px ones.
    a = line((10, 50), (40, 50))
    b = line((45, 50), (75, 50))
    others = [
        line((10, 15), (40, 18)),
        line((70, 15), (100, 18)),
        line((10, 85), (40, 88)),
        line((70, 85), (100, 88)),
    ]
    fs = detect_frame(_frame([a, b, *others]))
    assert len(fs) == 6
    for c in (a, b):
        _, ea, eb = _match(fs, c[0], c[-1])
        assert ea < 0.8 and eb < 0.8
