"""Centre-line refinement (blurtrack.detect.lines.centreline): where a line's ends are cut."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect import detect_frame
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.lines.centreline import (
    _cross_samples,
    raw_flank_sigma,
    refine_lines,
    tail_sigma,
)
from blurtrack.detect.lines.ragged import Ragged, arc_lengths
from blurtrack.detect.params import DetectParams, LinesParams
from blurtrack.testing.streak_frames import (
    outward_errors,
    quantise,
    render_streaks,
    saturated_grid,
)

#: Faint tails off (``lines.tail_min_px`` infinite): the lines end at a quarter of the peak.
NO_TAILS = DetectParams(lines=LinesParams(tail_min_px=np.inf))


def _frame(shape: tuple[int, int], curves: list[np.ndarray], seed: int) -> np.ndarray:
    """The streaks of ``curves`` rendered (sigma 1.3 px, light noise) and quantised."""
    return quantise(
        render_streaks(shape, curves, flux_per_px=0.8, sigma_px=1.3, noise=0.004, seed=seed)
    )


def _hooked(x0: float, y0: float) -> np.ndarray:
    """A dot that lingers on a 5 px hook for 35 % of the exposure, then runs 80 px: the
    hook's light per px is ten times the tail's (``hard``'s "hockey sticks")."""
    t = np.linspace(0.0, 1.0, 1600)
    hook = t < 0.35
    u = np.where(hook, 5.0 * t / 0.35, 5.0 + 80.0 * (t - 0.35) / 0.65)
    y = y0 + np.where(hook, 3.0 * (1.0 - t / 0.35) ** 2, 0.0)
    return np.stack([x0 + u, y], axis=1)


def test_a_line_along_a_bright_hook_and_its_tail_is_kept_whole() -> None:
    curves = [_hooked(40.0 + 130.0 * i, 50.0 + 60.0 * j) for i in range(3) for j in range(4)]
    image = _frame((300, 440), curves, seed=2)
    p = DetectParams()
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    coarse = [c[::80] for c in curves]  # the placed curves: the whole streak, coarsely
    arc = np.array([float(np.sum(np.hypot(*np.diff(c, axis=0).T))) for c in curves])
    _, kept = arc_lengths(refine_lines(prep.smooth, coarse, 1.6, p.lines, None, 3.0).lines)
    # Kept: the whole streak plus the final pass's extensions past both ends (3 sigma + 3).
    assert np.all(kept > arc) and np.all(kept < arc + 2 * (3 * 1.6 + 3) + 2)
    # Negative control: cut at a quarter of the peak (the first pass's rule) without the faint
    # tails, every line keeps little more than its hook.
    _, cut = arc_lengths(refine_lines(prep.smooth, coarse, 1.6, NO_TAILS.lines, None).lines)
    assert np.all(cut < 0.6 * arc)


def _speeding_up(x0: float, y0: float, k: float = 3.5, length: float = 90.0) -> np.ndarray:
    """A dot whose speed grows linearly from v to (1 + 2k) v over the exposure: its light per
    px fades from the start to an eighth of it at the end (``hard`` seed 4's streaks)."""
    t = np.linspace(0.0, 1.0, 1600)
    u = length * (t + k * t * t) / (1.0 + k)
    return np.stack([x0 + u, np.full_like(u, y0)], axis=1)


def _end_errors(fs: FrameStreaks, curves: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per curve, the nearest detection's start and end errors (px, either orientation)."""
    errs = []
    for c in curves:
        s, e = c[0], c[-1]
        same = np.hypot(*(fs.end_a - s).T) + np.hypot(*(fs.end_b - e).T)
        swap = np.hypot(*(fs.end_b - s).T) + np.hypot(*(fs.end_a - e).T)
        i = int(np.argmin(np.minimum(same, swap)))
        a, b = (fs.end_a[i], fs.end_b[i]) if same[i] <= swap[i] else (fs.end_b[i], fs.end_a[i])
        errs.append((np.hypot(*(a - s)), np.hypot(*(b - e))))
    out = np.array(errs)
    return out[:, 0], out[:, 1]


def test_a_streak_fading_towards_its_end_is_measured_to_its_end() -> None:
    curves = [_speeding_up(30.0 + 140.0 * i, 40.0 + 50.0 * j) for i in range(3) for j in range(4)]
    image = _frame((260, 450), curves, seed=3)
    fs = detect_frame(image)
    start_err, end_err = _end_errors(fs, curves)
    assert len(fs) == len(curves)
    assert np.all(start_err < 0.5) and np.all(end_err < 0.5)
    # Negative control: without the faint tails the lines stop where the light falls under a
    # quarter of the start's, 10-50 px short, and some streaks are lost.
    fs = detect_frame(image, NO_TAILS)
    _, end_err = _end_errors(fs, curves)
    assert len(fs) < len(curves)
    assert np.median(end_err) > 5.0


def test_faint_tails_leave_uniform_streaks_as_they_were() -> None:
    """Streaks of one brightness end in their caps' blur (runs under ``lines.tail_min_px``):
    their measured ends do not change."""
    curves = [
        np.stack([np.linspace(30.0, 110.0, 800) + 140.0 * i, np.full(800, 40.0 + 50.0 * j)], 1)
        for i in range(3)
        for j in range(4)
    ]
    image = _frame((260, 450), curves, seed=4)
    with_tails = detect_frame(image)
    without = detect_frame(image, NO_TAILS)
    np.testing.assert_array_equal(with_tails.end_a, without.end_a)
    np.testing.assert_array_equal(with_tails.end_b, without.end_b)


def test_the_flanks_of_saturated_streaks_give_the_raw_sigma() -> None:
    # Every streak saturated (27x): the unsmoothed flanks give the PSF's 1.5 px; the smoothed
    # image's clipped sections (the negative control) overstate it.
    img, _ = saturated_grid(27.0)
    p = DetectParams()
    prep = prepare_frame(img, p.smooth_sigma_px, p.hot_pixel_ratio)
    fs = detect_frame(img, DetectParams())
    lines = Ragged.from_list([np.asarray(c, float) for c in fs.points])
    sig = raw_flank_sigma(prep.signal, lines, 1.8, prep.saturation)
    assert sig is not None and abs(sig - 1.5) < 0.1
    v = _cross_samples(prep.smooth, lines, 12)[1]
    smoothed = np.nanmedian(tail_sigma(v, 12, 0.5 * prep.saturation))
    assert np.sqrt(smoothed**2 - 1.0) > 1.65
    # Too few sections: no sigma.
    assert raw_flank_sigma(prep.signal, Ragged.from_list(lines.split()[:1]), 1.8, 1.0) is None


def test_ends_of_streaks_saturated_many_times_over_stay_on_the_truth() -> None:
    # With the sigma from the smoothed flanks the ends of 4x to 27x saturated streaks lay
    # 0.3-0.6 px beyond the truth at the median; from the raw flanks within 0.15 px.
    for peak in (4.0, 27.0):
        img, truth = saturated_grid(peak)
        fs = detect_frame(img, DetectParams())
        out = np.concatenate(outward_errors(fs.end_a, fs.end_b, truth))
        assert abs(float(np.median(out))) < 0.15, (peak, np.median(out))
        assert float(np.max(np.abs(out))) < 0.8


def test_a_flank_sigma_wider_than_the_clipped_sections_is_not_taken(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The clipped sections overstate the sigma, never understate it: a flank fit above their
    # sigma (streaks piled on each other, a neighbour's light in the flanks) gives way to it,
    # the very ends as without a flank fit; one below it is taken (the ends move).
    import blurtrack.detect.lines.measure as measure

    img, _ = saturated_grid(27.0)
    runs = {}
    for name, sigma in (("none", None), ("wide", 25.0), ("own", "own")):
        if sigma == "own":
            monkeypatch.undo()
        else:
            monkeypatch.setattr(measure, "raw_flank_sigma", lambda *a, s=sigma: s)
        runs[name] = detect_frame(img, DetectParams())
    np.testing.assert_array_equal(runs["wide"].end_a, runs["none"].end_a)
    np.testing.assert_array_equal(runs["wide"].end_b, runs["none"].end_b)
    assert not np.array_equal(runs["own"].end_a, runs["none"].end_a)
