"""Template separation of touching streaks (blurtrack.detect.separation.separate) and the artefact
filter (blurtrack.detect.lines.segment.drop_artefacts), on exactly rendered frames."""

from __future__ import annotations

import cv2
import numpy as np

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.testing.streak_frames import quantise, render_streaks

SHAPE = (360, 480)


def _curve(origin: np.ndarray, n: int = 600) -> np.ndarray:
    """Every dot's curve: a 40 px arc down and to the right, sampled uniformly in time."""
    t = np.linspace(0.0, 1.0, n)
    return origin + np.stack([14.0 * t + 5.0 * np.sin(np.pi * t), 36.0 * t], axis=1)


def _ends(curve: np.ndarray) -> np.ndarray:
    return np.stack([curve[0], curve[-1]])


def _frame() -> tuple[np.ndarray, list[np.ndarray]]:
    """Twelve isolated streaks and three chains of two: the second dot's streak starts where
    the first one's ends, 3 px to the side (a dense grid under camera shake)."""
    curves = [
        _curve(np.array([30.0 + 70.0 * i, 20.0 + 90.0 * j])) for i in range(6) for j in range(2)
    ]
    step = _curve(np.zeros(2))[-1] + [3.0, 1.0]
    for k in range(3):
        a = _curve(np.array([40.0 + 150.0 * k, 210.0]))
        curves += [a, _curve(a[0] + step)]
    image = render_streaks(SHAPE, curves, flux_per_px=1.0, sigma_px=1.3, noise=0.004, seed=2)
    return quantise(image), curves


def _matched(fs, curves: list[np.ndarray], tol: float) -> int:
    """How many true streaks have a detection with both ends (either order) within ``tol``."""
    found = 0
    det = np.stack([fs.end_a, fs.end_b], axis=1)
    for c in curves:
        e = _ends(c)
        d = np.minimum(
            np.abs(det - e[None]).max(axis=(1, 2)), np.abs(det - e[None, ::-1]).max(axis=(1, 2))
        )
        found += int(np.any(d < tol))
    return found


def test_chains_of_touching_streaks_are_split_by_the_template() -> None:
    image, curves = _frame()
    fs = detect_frame(image)
    assert _matched(fs, curves, 1.0) == len(curves) == len(fs)
    # Negative control: without separation the chains come out as single long streaks.
    plain = detect_frame(image, DetectParams(separate=False))
    assert _matched(plain, curves, 1.0) <= len(curves) - 3


def test_separated_ends_are_accurate() -> None:
    image, curves = _frame()
    fs = detect_frame(image)
    det = np.stack([fs.end_a, fs.end_b], axis=1)
    errs = []
    for c in curves[12:]:  # the chained ones
        e = _ends(c)
        d = np.minimum(
            np.linalg.norm(det - e[None], axis=2).max(axis=1),
            np.linalg.norm(det - e[None, ::-1], axis=2).max(axis=1),
        )
        errs.append(d.min())
    assert max(errs) < 0.6


def test_faint_artefacts_next_to_bright_streaks_are_dropped() -> None:
    bright = _curve(np.array([100.0, 60.0]))
    ghost = _curve(np.array([112.0, 60.0]))[::3]  # 12 px to the side, 4 % of the light
    alone = _curve(np.array([340.0, 200.0]))
    image = render_streaks(
        SHAPE, [bright, ghost, alone], flux_per_px=[2.0, 0.08, 0.08], sigma_px=1.3, noise=0.002
    )
    image = quantise(image, np.uint16)
    fs = detect_frame(image)
    assert _matched(fs, [bright, alone], 1.0) == 2 and len(fs) == 2
    # Negative control: with the filter off the ghost is a streak of its own (its start
    # pulled towards the bright neighbour: what such ghosts do to a table).
    every = detect_frame(image, DetectParams(artefact_ratio=0.0))
    assert len(every) == 3 and _matched(every, [bright, alone], 1.0) == 2
    ghost_end = np.minimum(
        np.linalg.norm(every.end_a - ghost[-1], axis=1),
        np.linalg.norm(every.end_b - ghost[-1], axis=1),
    )
    assert ghost_end.min() < 1.0


def _first_pass(image: np.ndarray):  # type: ignore[no-untyped-def]
    """The first pass of detect_frame up to separation: the frame (saturation ignored), the
    folded components, lines."""
    from blurtrack.detect.context import FrameContext
    from blurtrack.detect.frame import _first_lines
    from blurtrack.detect.image import prepare_frame
    from blurtrack.detect.lines.measure import measure_lines
    from blurtrack.detect.lines.segment import axis_polylines, find_components

    p = DetectParams()
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    thr = max(p.threshold_snr * prep.noise_smooth, p.min_threshold)
    comps = find_components(prep.smooth, thr, p.min_area_px, p.max_streaks)
    sigma_c = float(np.sqrt(1.5**2 + 1.0 + 1.0 / 12.0))
    polys, folded = axis_polylines(prep.smooth, comps, sigma_c)
    ls = _first_lines(comps, polys, folded, 2.0 * sigma_c + 3.0)
    ctx = FrameContext(
        prep.smooth, prep.signal, prep.saturation, None, comps, thr, prep.noise_smooth, p
    )
    m = measure_lines(ctx, ls, sigma_c, True)
    return ctx, folded, m


def _collapse(m, i: int) -> None:  # type: ignore[no-untyped-def]
    """Make streak ``i``'s measured line a 1 px stub at its midpoint."""
    mid = m.time_mid[i]
    half = np.array([0.5, 0.0])
    m.end_a[i], m.end_b[i] = mid - half, mid + half
    m.length_px[i] = 1.0
    m.points[i] = np.stack([m.end_a[i], m.end_b[i]])


def test_a_collapsed_line_is_measured_again_with_the_template() -> None:
    from dataclasses import replace

    import blurtrack.detect.separation.separate as sep
    from blurtrack.detect.params import SeparationParams

    image, curves = _frame()
    ctx, folded, m = _first_pass(image)
    # The isolated streak nearest the frame's middle (12 isolated ones: curves[:12]).
    target = curves[4]
    i = int(np.argmin(np.linalg.norm(m.time_mid - target[len(target) // 2], axis=1)))
    _collapse(m, i)
    c = int(m.own[i])

    out = sep.separate(ctx, m, folded)
    assert out.replaced is not None and out.replaced[c] and out.streaks is not None
    rows = np.flatnonzero(out.streaks.own == c)
    assert rows.size == 1
    e = _ends(target)
    got = np.stack([out.streaks.end_a[rows[0]], out.streaks.end_b[rows[0]]])
    err = min(np.abs(got - e).max(), np.abs(got - e[::-1]).max())
    assert err < 1.0
    # Negative control: without the stub rule the collapsed line stands (one plain line in
    # a component of a reference's area).
    no_stubs = DetectParams(separation=SeparationParams(stub_fraction=0.0))
    again = sep.separate(replace(ctx, params=no_stubs), m, folded)
    assert again.replaced is None or not again.replaced[c]


def _own_image(img: np.ndarray, pl: list, k: int, pad: int, raw: bool) -> np.ndarray:
    """Placement ``k``'s own image straight from the definition: the frame less every other
    placement's template warped to its sub-pixel place over the whole frame (float64), cut to
    the placement's box plus ``pad`` (zeros past the frame)."""
    H, W = img.shape
    rest = img.astype(np.float64)
    for j, q in enumerate(pl):
        if j == k:
            continue
        x, y, w, h = q.tpl.box
        m = np.array([[1.0, 0.0, x + q.shift[0]], [0.0, 1.0, y + q.shift[1]]])
        src = q.tpl.raw if raw else q.tpl.smooth  # float32, as stored
        moved = cv2.warpAffine(src, m, (W, H), flags=cv2.INTER_LINEAR, borderValue=0.0)
        rest -= q.amp * moved.astype(np.float64)
    p = pl[k]
    x, y, w, h = p.tpl.box
    ox, oy = int(np.floor(x + p.shift[0])) - pad, int(np.floor(y + p.shift[1])) - pad
    out = np.zeros((h + 2 * pad + 1, w + 2 * pad + 1))
    fx0, fy0 = max(ox, 0), max(oy, 0)
    fx1, fy1 = min(ox + out.shape[1], W), min(oy + out.shape[0], H)
    out[fy0 - oy : fy1 - oy, fx0 - ox : fx1 - ox] = rest[fy0:fy1, fx0:fx1]
    return out


def test_the_mosaic_holds_each_placements_own_image_and_clips_in_place() -> None:
    from blurtrack.detect.gyro.gyrocurve import curve_template
    from blurtrack.detect.separation.mosaic import placement_mosaic
    from blurtrack.detect.separation.templates import Placement

    rng = np.random.default_rng(5)
    H, W = 90, 140
    smooth = rng.normal(0.0, 0.02, (H, W)).astype(np.float32)
    signal = rng.normal(0.0, 0.03, (H, W)).astype(np.float32)
    t = np.linspace(0.0, 1.0, 65)[:, None]
    # Three streaks side by side (their templates overlap), one reaching past the left border.
    starts = [(20.0, 20.0), (24.5, 23.2), (-6.0, 50.0)]
    pl = []
    for i, (x, y) in enumerate(starts):
        curve = np.array([x, y]) + t * np.array([38.0, 14.0])
        tpl = curve_template(curve, 1.6, 1.2, 30.0, None, with_raw=True)
        frac = rng.uniform(-0.5, 0.5, 2)  # sub-pixel shifts
        pl.append(Placement(tpl, frac, 0.7 + 0.2 * i, i))
    pad = 6
    mos_s, mos_r, lines, back = placement_mosaic(smooth, signal, pl, pad)
    tiles = []
    for k, p in enumerate(pl):
        x, y, w, h = p.tpl.box
        ox, oy = int(np.floor(x + p.shift[0])) - pad, int(np.floor(y + p.shift[1])) - pad
        tx, ty = round(float(ox - back[k, 0])), round(float(oy - back[k, 1]))
        tiles.append((slice(ty, ty + h + 2 * pad + 1), slice(tx, tx + w + 2 * pad + 1)))
        np.testing.assert_allclose(lines[k] + back[k], p.tpl.points + p.shift, atol=1e-9)
    # The mosaic outside the tiles is zero (each own image lies in its zeros).
    inside = np.zeros(mos_s.shape, bool)
    for tile in tiles:
        assert not inside[tile].any()  # the tiles do not overlap
        inside[tile] = True
    assert not mos_s[~inside].any() and not mos_r[~inside].any()
    for k, tile in enumerate(tiles):
        own_s = _own_image(smooth, pl, k, pad, raw=False)
        own_r = _own_image(signal, pl, k, pad, raw=True)
        np.testing.assert_allclose(mos_s[tile], own_s, atol=2e-6)
        np.testing.assert_allclose(mos_r[tile], own_r, atol=2e-6)
    # Negative control: the neighbours' templates were subtracted (the first streak's own
    # image is not the frame's crop).
    crop = _own_image(smooth, pl[:1], 0, pad, raw=False)
    assert np.abs(mos_s[tiles[0]] - crop).max() > 0.1
    # Clipped in place, the mosaic holds each own image clipped at zero, its gaps still zero.
    for img in (mos_s, mos_r):
        np.maximum(img, 0.0, out=img)
    for k, tile in enumerate(tiles):
        own_s = np.maximum(_own_image(smooth, pl, k, pad, raw=False), 0.0)
        np.testing.assert_allclose(mos_s[tile], own_s, atol=2e-6)
    assert not mos_s[~inside].any()
