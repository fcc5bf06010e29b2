"""Centre-line refinement (blurtrack.detect.centreline): where a line's ends are cut."""

from __future__ import annotations

import numpy as np

from blurtrack.detect.centreline import refine_lines
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.params import DetectParams
from blurtrack.detect.ragged import arc_lengths
from blurtrack.testing.streak_frames import quantise, render_streaks


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
    image = quantise(
        render_streaks((300, 440), curves, flux_per_px=0.8, sigma_px=1.3, noise=0.004, seed=2)
    )
    p = DetectParams()
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    coarse = [c[::80] for c in curves]  # the placed curves: the whole streak, coarsely
    arc = np.array([float(np.sum(np.hypot(*np.diff(c, axis=0).T))) for c in curves])
    _, kept = arc_lengths(refine_lines(prep.smooth, coarse, 1.6, None, 3.0).lines)
    # Kept: the whole streak plus the final pass's extensions past both ends (3 sigma + 3).
    assert np.all(kept > arc) and np.all(kept < arc + 2 * (3 * 1.6 + 3) + 2)
    # Negative control: cut at a quarter of the peak (the first pass's rule), every line
    # keeps little more than its hook.
    _, cut = arc_lengths(refine_lines(prep.smooth, coarse, 1.6, None, None).lines)
    assert np.all(cut < 0.6 * arc)
