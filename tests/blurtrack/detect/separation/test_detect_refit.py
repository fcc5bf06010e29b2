"""Joint refinement of overlapping template placements (blurtrack.detect.separation.refit), on
exactly rendered streaks whose true positions are known."""

from __future__ import annotations

import numpy as np

from blurtrack.detect import DetectParams
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.lines.segment import find_components
from blurtrack.detect.separation.refit import _paint, _peak, _tile, refit
from blurtrack.detect.separation.templates import Placement, Template, template
from blurtrack.testing.streak_frames import quantise, render_streaks

SHAPE = (160, 240)
V = np.array([40.0, 8.0])  # every streak's start-to-end vector
U = V / np.linalg.norm(V)
N = np.array([-U[1], U[0]])
REF = np.array([20.0, 20.0])  # where the template's streak starts
SP = DetectParams().separation  # the separation section's defaults


def _line(origin: np.ndarray, n: int = 600) -> np.ndarray:
    return origin + np.linspace(0.0, 1.0, n)[:, None] * V


def _light(curves: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The prepared frame's smoothed light inside its components (what separation's
    residual holds), the smoothed and the raw signal."""
    image = quantise(render_streaks(SHAPE, curves, 1.0, 1.3, noise=0.002, seed=4), np.uint16)
    p = DetectParams()
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    thr = max(p.threshold_snr * prep.noise_smooth, p.min_threshold)
    comps = find_components(prep.smooth, thr, p.min_area_px, p.max_streaks)
    light = np.zeros(SHAPE, np.float32)
    light[comps.ys, comps.xs] = comps.values
    return light, prep.smooth, prep.signal


def _template() -> Template:
    ref = _line(REF)
    _, smooth, signal = _light([ref])
    p = DetectParams()
    thr = 6.0 * float(np.std(smooth[smooth < 0.02])) + p.min_threshold
    comps = find_components(smooth, thr, p.min_area_px, p.max_streaks)
    assert comps.ids.size == 1
    return template(smooth, signal, comps, 0, ref[[0, -1]])


def _pair(along: float, side: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two streaks running along each other: the second starts ``along`` x the length
    down the first and ``side`` px beside it. Returns the light and both true shifts of
    the template (its streak moved onto each)."""
    a0 = np.array([60.0, 90.0])
    b0 = a0 + along * V + side * N
    light, _, _ = _light([_line(a0), _line(b0)])
    return light, a0 - REF, b0 - REF


def test_overlapping_placements_slide_to_the_ends() -> None:
    tpl = _template()
    light, ta, tb = _pair(0.5, 3.0)
    # Where a greedy pursuit leaves them: both slid into the shared part (the correlation
    # of one template with the pair is flat there).
    start = [Placement(tpl, ta + 7.0 * U, 1.0, 0), Placement(tpl, tb - 5.0 * U, 1.0, 0)]
    out, model = refit(light, start, SP)
    assert model is not None
    for p, truth in zip(out, (ta, tb), strict=True):
        assert np.linalg.norm(p.shift - truth) < 0.3
        assert abs(p.amp - 1.0) < 0.1
    # Negative control: the residual of the starting placements is much larger.
    m0 = np.zeros_like(light)
    for p in start:
        _paint(m0, _tile(p), 1.0)
    assert np.sum((light - m0) ** 2) > 4.0 * np.sum((light - model) ** 2)


def test_placements_at_their_streaks_stay_there() -> None:
    tpl = _template()
    light, ta, tb = _pair(0.5, 3.0)
    out, model = refit(light, [Placement(tpl, ta, 1.0, 0), Placement(tpl, tb, 1.0, 0)], SP)
    assert model is not None
    assert all(np.linalg.norm(p.shift - t) < 0.3 for p, t in zip(out, (ta, tb), strict=True))


def test_closer_pairs_are_placed_as_well() -> None:
    # Streaks 1.5-2.5 px apart. The correlation peak is a ridge along the streak, here at
    # 11 degrees to the x axis: separate parabolas in x and y put the second placement
    # 1.1 px back along it (what the 3 x 3 quadratic fit of refit._peak avoids).
    tpl = _template()
    for along, side in ((0.5, 1.5), (0.6, 2.5)):
        light, ta, tb = _pair(along, side)
        start = [Placement(tpl, ta + 7.0 * U, 1.0, 0), Placement(tpl, tb - 5.0 * U, 1.0, 0)]
        out, _ = refit(light, start, SP)
        errs = [float(np.linalg.norm(p.shift - t)) for p, t in zip(out, (ta, tb), strict=True)]
        assert max(errs) < 0.3


def test_peak_of_a_diagonal_ridge() -> None:
    # A quadratic ridge along (cos 20 deg, sin 20 deg) whose top lies at (0.4, 0.3) off the
    # sampled maximum: the 3 x 3 fit finds it, separate parabolas do not.
    yy, xx = np.mgrid[-3:4, -3:4].astype(float)
    d = np.array([np.cos(0.35), np.sin(0.35)])
    u = (xx - 0.4) * d[0] + (yy - 0.3) * d[1]
    v = -(xx - 0.4) * d[1] + (yy - 0.3) * d[0]
    surface = 10.0 - 0.05 * u**2 - 2.0 * v**2
    iy, ix = np.unravel_index(int(np.argmax(surface)), surface.shape)
    fx, fy = _peak(surface, int(iy), int(ix))
    assert abs(ix + fx - 3.4) < 1e-6 and abs(iy + fy - 3.3) < 1e-6
    row, col = surface[iy, ix - 1 : ix + 2], surface[iy - 1 : iy + 2, ix]
    px = 0.5 * (row[0] - row[2]) / (row[0] - 2 * row[1] + row[2])
    py = 0.5 * (col[0] - col[2]) / (col[0] - 2 * col[1] + col[2])
    assert np.hypot(ix + px - 3.4, iy + py - 3.3) > 0.1  # the separable estimate is off


def test_placements_that_do_not_meet_are_left_alone() -> None:
    tpl = _template()
    light, ta, _ = _pair(0.5, 1.5)
    far = Placement(tpl, ta + np.array([120.0, 0.0]), 1.0, 1)  # over dark sky
    near = Placement(tpl, ta + 7.0 * U, 1.0, 0)
    out, model = refit(light, [near, far], SP)
    assert model is None and out[0] is near and out[1] is far
