"""The image doubts the gyro may lift (quality._frame_quality's ``single``): how a crossing
counts, on separated crossings of rendered frames too, and a frame without a consensus."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.separation.quality import _frame_quality, frame_quality
from blurtrack.testing.streak_frames import quantise, render_streaks


def _quality(
    crossing: np.ndarray, lit: np.ndarray, clean: int = 8
) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """The quality columns and ``single`` of four streaks (``crossing (4,)``, ``lit (4, 2)``:
    light beyond each end) among ``clean`` clean ones, the four first."""
    n = 4 + clean
    rng = np.random.default_rng(0)
    v = np.tile([30.0, 4.0], (n, 1)) + rng.normal(0, 0.2, (n, 2))
    mid = rng.uniform(0, 400, (n, 2))
    flags = {k: np.zeros(n, bool) for k in ("clipped", "merged", "crossing", "looped", "saturated")}
    flags["crossing"][:4] = crossing
    light = np.zeros((n, 2))
    light[:4] = np.where(lit, 1.0, 0.0)
    p = DetectParams()
    cols, single = _frame_quality(
        v,
        mid,
        flags,
        np.full(n, 1.9),
        np.full(n, "point", object),
        light,
        p.source,
        p.quality,
        np.zeros(n, bool),
    )
    return tuple(c[:4] for c in cols), single[:4]


def test_a_crossing_does_not_count_against_the_one_doubt_the_gyro_lifts() -> None:
    lit = np.array([[True, False], [False, True], [True, True], [False, False]])
    # 0, 1: a crossing and one lit end: one doubt (the crossing's light runs across the
    # streak); 2: both ends lit: two, crossing or not; 3: a crossing alone: one.
    assert _quality(np.ones(4, bool), lit)[1].tolist() == [True, True, False, True]
    # Negative control: without the crossing, the lit ends alone count the same, and a
    # streak with no doubt at all has nothing to lift.
    assert _quality(np.zeros(4, bool), lit)[1].tolist() == [True, True, False, False]


def test_a_frame_without_consensus_leaves_one_doubt_for_the_gyro() -> None:
    # Four point lights (one fewer than min_reference clean ones): none ok, each with one
    # doubt (the shape nothing checks), which the gyro's vector may lift; a lit end makes two.
    assert DetectParams().quality.min_reference > 4
    lit = np.array([[False, False], [False, False], [False, False], [True, False]])
    (dev, _, ok, _, reason), single = _quality(np.zeros(4, bool), lit, clean=0)
    assert np.isnan(dev).all() and not ok.any()
    assert reason.tolist() == ["ends_unsure"] * 3 + ["chained"]
    assert single.tolist() == [True, True, True, False]
    # Negative control: with the clean streaks, the consensus exists and the three are ok.
    (dev, _, ok, _, _), single = _quality(np.zeros(4, bool), lit)
    assert np.isfinite(dev).all() and ok.tolist() == [True, True, True, False]
    assert single.tolist() == [False, False, False, True]


def _arc(x0: float, y0: float) -> np.ndarray:
    """A dot's path: 60 px across, bowed 30 px (every dot of a frame draws the same)."""
    t = np.linspace(0.0, 1.0, 800)
    return np.column_stack([x0 + 60.0 * t, y0 - 30.0 * np.sin(np.pi * t)])


def _frame(shift: float, refs: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Two dots' paths ``shift`` px apart at y = 80 (they cross 10 to 14 px before the first
    one's end), one alone at x = 200, and ``refs`` more in rows of four below."""
    curves = [_arc(30, 80), _arc(30 + shift, 80)]
    curves += [_arc(30 + 80 * (k % 4), 170 + 80 * (k // 4)) for k in range(refs)]
    curves += [_arc(200, 80)]
    return curves, quantise(render_streaks((280, 360), curves, 0.8, 1.5, 0.03, 0.003, 5))


def test_a_separated_crossing_near_one_end_is_one_doubt() -> None:
    # With a consensus (nine clean streaks), separation measures the crossing pair apart:
    # both flagged crossing, both ends within 0.5 px, one doubt each (the gyro may lift it).
    curves, img = _frame(36.0, 8)
    p = DetectParams()
    fs = detect_frame(img, p)
    (_, _, ok, _, reason), single = frame_quality(fs, p)
    for dot in (0, 1):
        c = curves[dot]
        same = np.maximum(np.hypot(*(fs.end_a - c[0]).T), np.hypot(*(fs.end_b - c[-1]).T))
        k = int(np.argmin(same))
        assert same[k] < 0.5 and fs.flags["crossing"][k]
        assert reason[k] == "crossing" and single[k] and not ok[k]


@pytest.mark.parametrize("shift", [36.0, 40.0, 44.0])
def test_a_crossing_far_from_both_ends_of_a_chimera_stays_a_doubt(shift: float) -> None:
    # Negative control for trusting a crossing: two dots' bowed paths, ``shift`` px apart,
    # cross 10 to 14 px before the first one's end; the skeleton pairs the straightest
    # continuation at the crossing, so one path runs from the first dot's start to the second
    # one's end (a chimera of two streaks) with the crossing in its middle, and without a
    # consensus its shape says nothing: were a crossing no doubt, the chimera would be
    # quality_ok. It stays ``crossing``; the gyro's vector check, all that may confirm it,
    # refuses it: its vector is far from every dot's (the prediction).
    curves, img = _frame(shift, 3)  # four clean streaks: too few for a consensus
    p = DetectParams()
    fs = detect_frame(img, p)
    # The chimera: from the first dot's start (within 1 px) far past its end (over 80 px).
    start = curves[0][0]
    near = np.minimum(np.hypot(*(fs.end_a - start).T), np.hypot(*(fs.end_b - start).T))
    chimera = (near < 1.0) & (np.hypot(*(fs.end_b - fs.end_a).T) > 80.0)
    assert chimera.sum() == 1
    k = int(np.flatnonzero(chimera)[0])
    assert fs.flags["crossing"][k]
    (_, _, ok, _, reason), _ = frame_quality(fs, p)
    assert not ok[k] and reason[k] == "crossing"
    v = fs.end_b[k] - fs.end_a[k]
    dot = curves[0][-1] - curves[0][0]
    off = min(np.hypot(*(v - dot)), np.hypot(*(v + dot)))
    assert off > 10 * p.source.gyro_vector_tol_px
