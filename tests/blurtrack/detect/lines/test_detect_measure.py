"""Measuring lines (:mod:`blurtrack.detect.lines.measure`): short point lights in a frame whose
median line is an extended source's, measured with their own width."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect.frame import detect_frame
from blurtrack.detect.lines.measure import NARROW_SHARE, _narrower_than_frame
from blurtrack.testing.streak_frames import line, line_grid, quantise, render_streaks

#: The wide lights' and the narrow lights' spread (px).
WIDE_SIGMA, NARROW_SIGMA = 4.0, 1.2


def _lamps_beside_glare(peak: float) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """A 300 x 500 8-bit frame: 12 broad lights (sigma 4 px, 41 px long, peak 0.5 of full
    scale: lit bands, glare) and, below them, 6 short point lights (sigma 1.2 px, 12.2 px
    long) of plateau ``peak`` times full scale; with the short ones' true ends."""
    wide = line_grid(12, 6, (40.0, 40.0), (75.0, 70.0), (40.0, 8.0))
    ends = [
        (np.array([40.0 + k * 75.0, 220.0]), np.array([50.0 + k * 75.0, 227.0])) for k in range(6)
    ]
    norm = np.sqrt(2.0 * np.pi)
    image = render_streaks((300, 500), wide, 0.5 * WIDE_SIGMA * norm, WIDE_SIGMA, 0.03, 0.004, 1)
    image += render_streaks(
        (300, 500), [line(a, b) for a, b in ends], peak * NARROW_SIGMA * norm, NARROW_SIGMA, 0.0
    )
    return quantise(image), ends


def _worse_end_error(fs, a: np.ndarray, b: np.ndarray) -> float:
    """The worse end's distance (px) of the detection nearest the segment ``a``-``b``, either
    way round; infinite when none lies within 5 px of its middle."""
    d = np.hypot(*(0.5 * (fs.end_a + fs.end_b) - 0.5 * (a + b)).T)
    if d.size == 0 or d.min() > 5.0:
        return float("inf")
    i = int(np.argmin(d))
    ea, eb = fs.end_a[i], fs.end_b[i]
    return float(
        min(
            max(np.hypot(*(ea - a)), np.hypot(*(eb - b))),
            max(np.hypot(*(ea - b)), np.hypot(*(eb - a))),
        )
    )


@pytest.mark.parametrize("peak", [0.6, 3.0, 20.0])
def test_short_lights_beside_broad_ones_keep_their_ends(peak: float) -> None:
    image, ends = _lamps_beside_glare(peak)
    fs = detect_frame(image)
    # The frame's sigma is the broad lights' (the majority): the short lights' smoothed sigma
    # is under it by more than the point ratio, and fitted with it they were lost (none within
    # 5 px) before their own width was used.
    assert fs.sigma_c_px > 1.5 * np.hypot(NARROW_SIGMA, 1.0)
    errors = [_worse_end_error(fs, a, b) for a, b in ends]
    assert max(errors) < 0.35, errors  # unsaturated, 3x and 20x the saturation


def test_narrow_lines_are_a_population_not_a_few_artefacts() -> None:
    sigma_c = 3.0
    wide = np.full(40, 3.0)
    # Under sigma / 1.5 = 2: narrow. One line in 41 (a line cut at the border): not a population.
    one = np.r_[wide, 1.5]
    assert not _narrower_than_frame(one, sigma_c, 1.5).any()
    # A tenth of the lines or more: the frame's sigma is not theirs.
    k = int(np.ceil(NARROW_SHARE * 45))
    some = np.r_[wide[: 45 - k], np.full(k, 1.5)]
    got = _narrower_than_frame(some, sigma_c, 1.5)
    np.testing.assert_array_equal(got, some < 2.0)
    # NaN widths (not measured) are neither narrow nor counted; the boundary is strict.
    edge = np.r_[np.full(8, 3.0), 2.0, np.nan, 1.9, 1.9]
    np.testing.assert_array_equal(
        _narrower_than_frame(edge, sigma_c, 1.5), [False] * 10 + [True, True]
    )


def test_a_laser_frame_has_no_narrow_lines() -> None:
    # Every dot's width within a few per cent of the median: the rule leaves it alone.
    rng = np.random.default_rng(4)
    widths = 1.8 * (1.0 + 0.03 * rng.standard_normal(300))
    assert not _narrower_than_frame(widths, float(np.median(widths)), 1.5).any()
