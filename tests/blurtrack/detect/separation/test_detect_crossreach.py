"""Which ends a crossing streak's neighbour reaches (blurtrack.detect.separation.crossreach),
and how that crossing counts among the doubts the gyro may lift (quality._frame_quality)."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.separation.crossreach import crossing_ends, end_reach, light_radius
from blurtrack.detect.separation.quality import _frame_quality, frame_quality
from blurtrack.testing.streak_frames import quantise, render_streaks

SIGMA = 1.87  # the hard preset's cross-section sigma


def _seg(p0: tuple[float, float], p1: tuple[float, float]) -> np.ndarray:
    n = int(np.ceil(np.hypot(p1[0] - p0[0], p1[1] - p0[1]))) + 1
    return np.column_stack([np.linspace(p0[0], p1[0], n), np.linspace(p0[1], p1[1], n)])


def _cross_at(x: float, length: float = 80.0) -> list[np.ndarray]:
    """A horizontal streak from (0, 50) to (length, 50) and a vertical one through x."""
    return [_seg((0.0, 50.0), (length, 50.0)), _seg((x, 10.0), (x, 90.0))]


def test_the_reach_follows_the_profile_and_the_edge_fit() -> None:
    # ceil(3 sigma) + 1 + 3 sigma; beyond 3 sigma + 1, inside 2 sigma + 7 - 1.
    assert light_radius(SIGMA) == pytest.approx(7.0 + 3 * SIGMA)
    assert end_reach(SIGMA) == pytest.approx((3 * SIGMA + 1, 2 * SIGMA + 6))


def test_a_crossing_far_from_both_ends_reaches_neither() -> None:
    lim = light_radius(SIGMA) + end_reach(SIGMA)[1]  # 22.3 px: nearer reaches an end
    for x in (lim + 1.0, 40.0, 80.0 - lim - 1.0):
        got = crossing_ends(_cross_at(x), np.array([True, False]), SIGMA, np.zeros(2, bool))
        assert not got[0].any(), x


@pytest.mark.parametrize("x", [-5.0, 0.0, 4.0, 12.0, 20.0])
def test_a_crossing_near_end_a_reaches_end_a_only(x: float) -> None:
    got = crossing_ends(_cross_at(x), np.array([True, True]), SIGMA, np.zeros(2, bool))
    assert got[0].tolist() == [True, False]


def test_a_short_streak_reads_its_whole_profile() -> None:
    got = crossing_ends(_cross_at(40.0), np.array([True, False]), SIGMA, np.array([True, False]))
    assert got[0].tolist() == [True, True]
    alone = crossing_ends(_cross_at(40.0)[:1], np.array([True]), SIGMA, np.array([True]))
    assert not alone.any()  # no neighbour: nothing reaches


def _quality(cross_ends: np.ndarray | None, lit: np.ndarray) -> np.ndarray:
    n = 12
    rng = np.random.default_rng(0)
    v = np.tile([30.0, 4.0], (n, 1)) + rng.normal(0, 0.2, (n, 2))
    mid = rng.uniform(0, 400, (n, 2))
    flags = {k: np.zeros(n, bool) for k in ("clipped", "merged", "crossing", "looped", "saturated")}
    flags["crossing"][:4] = True
    light = np.zeros((n, 2))
    light[:4] = np.where(lit, 1.0, 0.0)
    p = DetectParams()
    ce = None if cross_ends is None else np.vstack([cross_ends, np.zeros((n - 4, 2), bool)])
    _, single = _frame_quality(
        v,
        mid,
        flags,
        np.full(n, 1.9),
        np.full(n, "point", object),
        light,
        p.source,
        p.quality,
        np.zeros(n, bool),
        ce,
    )
    return single[:4]


def test_a_crossing_at_a_lit_end_is_that_ends_doubt_only() -> None:
    lit = np.array([[True, False], [False, True], [True, False], [False, False]])
    reach = np.array([[True, False], [True, False], [False, False], [True, False]])
    # 0: crossing and light at end A: one doubt; 1: crossing at A, light at B: two;
    # 2: a crossing that reaches no end found and a lit end: two (as before);
    # 3: a crossing alone: one.
    assert _quality(reach, lit).tolist() == [True, False, False, True]
    # Without the reach (a table without centre lines): a crossing is always its own doubt.
    assert _quality(None, lit).tolist() == [False, False, False, True]


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


def test_a_separated_crossing_near_one_end_reaches_that_end_only() -> None:
    # With a consensus (nine clean streaks), separation measures the crossing pair apart:
    # both flagged crossing, both ends within 0.5 px; the crossing reaches the end near it
    # (the first dot's end, the second one's start) and not the other: one doubt each.
    curves, img = _frame(36.0, 8)
    p = DetectParams()
    fs = detect_frame(img, p)
    reach = crossing_ends(fs.points, fs.flags["crossing"], fs.sigma_c_px, fs.short)
    (_, _, ok, _, reason), single = frame_quality(fs, p)
    for dot, near_end in ((0, 1), (1, 0)):
        c = curves[dot]
        same = np.maximum(np.hypot(*(fs.end_a - c[0]).T), np.hypot(*(fs.end_b - c[-1]).T))
        k = int(np.argmin(same))
        assert same[k] < 0.5 and fs.flags["crossing"][k]
        assert reach[k].tolist() == [near_end == 0, near_end == 1]
        assert reason[k] == "crossing" and single[k] and not ok[k]


@pytest.mark.parametrize("shift", [36.0, 40.0, 44.0])
def test_a_crossing_far_from_both_ends_of_a_chimera_stays_a_doubt(shift: float) -> None:
    # Negative control for trusting a crossing far from the ends: two dots' bowed paths,
    # ``shift`` px apart, cross 10 to 14 px before the first one's end; the skeleton pairs
    # the straightest continuation at the crossing, so one path runs from the first dot's
    # start to the second one's end (a chimera of two streaks) with the crossing in its
    # middle, beyond both ends' reach, and without a consensus its shape says nothing: were a
    # crossing beyond the ends' reach no doubt, the chimera would be quality_ok. It stays
    # ``crossing`` (the gyro's vector check is all that may confirm it).
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
    reach = crossing_ends(fs.points, fs.flags["crossing"], fs.sigma_c_px, fs.short)
    assert not reach[k].any()
    (_, _, ok, _, reason), _ = frame_quality(fs, p)
    assert not ok[k] and reason[k] == "crossing"
