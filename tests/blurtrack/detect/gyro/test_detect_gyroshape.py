"""The gyro pass's template rendering and shape-search trial (blurtrack.detect.gyro.gyrocurve,
blurtrack.detect.gyro.gyroshape) against plain reference computations: splats summed by
``np.add.at`` and blurred by ``cv2.GaussianBlur``; the ranking correlations summed
placement by placement."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.detect.gyro import gyroshape
from blurtrack.detect.gyro.gyrocurve import _blurred, _splat, curve_template
from blurtrack.detect.gyro.gyroshape import DEN_FLOOR, SHIFT_WINDOW_PX, _trial
from blurtrack.detect.params import SeparationParams

INSIDE_MIN = SeparationParams().inside_min


def _splat_blur(pts: np.ndarray, sigma: float, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    img = np.zeros((h, w))
    u, v = pts[:, 0] - x0, pts[:, 1] - y0
    iu, iv = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - iu, v - iv
    for du, dv, k in (
        (0, 0, (1 - fu) * (1 - fv)),
        (1, 0, fu * (1 - fv)),
        (0, 1, (1 - fu) * fv),
        (1, 1, fu * fv),
    ):
        ok = (iu + du >= 0) & (iu + du < w) & (iv + dv >= 0) & (iv + dv < h)
        np.add.at(img, (iv[ok] + dv, iu[ok] + du), k[ok] / len(pts))
    s = float(np.sqrt(max(sigma * sigma - 1.0 / 6.0, 0.09)))
    return np.asarray(cv2.GaussianBlur(img, (0, 0), s, borderType=cv2.BORDER_CONSTANT))


def _curve(rng: np.random.Generator, x: float, y: float) -> np.ndarray:
    t = np.linspace(0.0, 1.0, 65)
    return np.stack([x + 12.0 * np.sin(3.0 * t), y + 15.0 * t + 3.0 * rng.random() * t * t], 1)


@pytest.mark.parametrize("sigma", [0.3, 1.3, 2.2])
def test_render_is_the_splatted_curve_blurred(sigma: float) -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        pts = _curve(rng, 30.0 + rng.random(), 20.0 + rng.random())
        # Grids that cut the curve too: splats off the grid are dropped.
        x0, y0 = int(rng.integers(15, 35)), int(rng.integers(10, 30))
        w, h = int(rng.integers(4, 40)), int(rng.integers(4, 40))
        ref = _splat_blur(pts, sigma, x0, y0, w, h)
        got = _blurred(_splat(pts, x0, y0, w, h), sigma)
        assert got.shape == ref.shape
        assert np.abs(got - ref).max() <= 1e-15 * max(ref.max(), 1e-300)


def _brute(light: np.ndarray, box: tuple[int, int, int, int], tpl) -> tuple[float, tuple]:
    """The best halo-normalised correlation over every placement _trial searches, summed
    placement by placement in float64, and the curve's shift there."""
    x, y, w, h = box
    tx, ty, tw, th = tpl.box
    H, W = light.shape
    mask = (tpl.support + tpl.halo).astype(float)
    sm = tpl.smooth.astype(float)
    best, at = -np.inf, (0, 0)
    top = 0.0
    dens = {}
    for Y in range(max(y - th // 2 - 2, 0), min(y + h + th // 2 + 2, H) - th + 1):
        for X in range(max(x - tw // 2 - 2, 0), min(x + w + tw // 2 + 2, W) - tw + 1):
            win = light[Y : Y + th, X : X + tw].astype(float)
            dens[X, Y] = (float(np.sum(win * sm)), float(np.sum(win * win * mask)))
            top = max(top, dens[X, Y][1])
    for (X, Y), (num, den) in dens.items():
        if den > DEN_FLOOR * top:
            r = num / np.sqrt(den * tpl.norm2)
            if r > best:
                best, at = r, (X - tx, Y - ty)
    return best, at


def test_the_trial_ranks_placements_by_their_own_sums_and_never_the_dark() -> None:
    rng = np.random.default_rng(5)
    H, W = 90, 110
    pts = _curve(rng, 50.0, 30.0)
    tpl = curve_template(pts, 1.6, 1.2, 40.0, None, with_raw=False)
    # A dot drawn by the curve shifted by (3, -2), a fainter one elsewhere, noise only on
    # the lit pixels (the light image holds the candidates' pixels, zero elsewhere).
    light = np.zeros((H, W), np.float32)
    tx, ty, tw, th = tpl.box
    light[ty - 2 : ty - 2 + th, tx + 3 : tx + 3 + tw] += 1.1 * tpl.smooth
    other = curve_template(_curve(rng, 20.0, 50.0), 1.6, 1.2, 15.0, None, with_raw=False)
    ox, oy, ow, oh = other.box
    light[oy : oy + oh, ox : ox + ow] += other.smooth
    lit = light > 0
    light[lit] += rng.normal(0.0, 0.01, lit.sum()).astype(np.float32)
    box = (tx + 8, ty + 5, tw - 10, th - 12)
    got, score, rank, shift, top = _trial(light, box, tpl, INSIDE_MIN)
    ref_rank, ref_shift = _brute(light, box, tpl)
    assert got is tpl
    assert shift == ref_shift == (3, -2)
    assert rank == pytest.approx(ref_rank, rel=1e-5)
    # Cauchy-Schwarz: neither correlation exceeds one (the unguarded ratio of rounding over
    # the dark placements did, by orders of magnitude).
    assert 0.95 < rank <= 1.0 + 1e-5 and 0.95 < score <= 1.0 + 1e-5
    # Searched about a placement within the window of the best one, the trial finds it again.
    assert SHIFT_WINDOW_PX >= 2
    near = _trial(light, box, tpl, INSIDE_MIN, (shift[0] - 2, shift[1] + 1, top))
    assert near[3] == shift and near[2] == pytest.approx(rank, rel=1e-5)
    # Nothing lit within reach: no trial.
    dark = np.zeros_like(light)
    assert _trial(dark, box, tpl, INSIDE_MIN)[0] is None


def test_the_shape_search_finds_a_rotated_and_scaled_curve(monkeypatch) -> None:
    # The light holds the curve rotated by 0.03 rad and scaled by 1.04 about its centroid:
    # the coordinate search's pick.
    from blurtrack.detect.gyro.gyrocurve import similar_curve
    from blurtrack.detect.lines.segment import find_components

    rng = np.random.default_rng(8)
    pts = _curve(rng, 60.0, 40.0)
    truth = similar_curve(pts, 1.04 * np.exp(0.03j))

    def make(c: np.ndarray):
        return curve_template(c, 1.6, 1.2, 40.0, None, with_raw=False)

    t = make(truth)
    light = np.zeros((100, 120), np.float32)
    tx, ty, tw, th = t.box
    light[ty : ty + th, tx : tx + tw] = t.smooth
    comps = find_components(light, 0.05 * float(light.max()), 5, 10)
    c = int(np.argmax(comps.areas))
    tpl, score = gyroshape.best_shape(light, comps, c, pts, make, INSIDE_MIN)
    assert tpl is not None and score > 0.999
    assert np.abs(tpl.points - truth).max() < 1e-9


def test_a_template_without_light_is_no_trial() -> None:
    # A curve that splats no light (predicted off the canvas, or a frame whose typical dot
    # holds none) explains nothing: no trial, and no 0 / 0 on the way (hard_long_dense_grid
    # 103 met such templates once its gyro was used).
    rng = np.random.default_rng(5)
    pts = _curve(rng, 50.0, 30.0)
    zero = curve_template(pts, 1.6, 1.2, 0.0, None, with_raw=False)
    assert zero.norm2 == 0.0
    lit = curve_template(pts, 1.6, 1.2, 40.0, None, with_raw=False)
    light = np.zeros((90, 110), np.float32)
    tx, ty, tw, th = lit.box
    light[ty : ty + th, tx : tx + tw] += lit.smooth
    box = (tx + 8, ty + 5, tw - 10, th - 12)
    with np.errstate(all="raise"):
        assert _trial(light, box, zero, INSIDE_MIN)[0] is None
        assert _trial(light, box, lit, INSIDE_MIN)[0] is lit  # the control: a lit one is tried
