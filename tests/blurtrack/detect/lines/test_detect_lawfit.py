"""Endpoints of short streaks under their predicted time law (``lines/lawfit.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect.lines.endpoints import fit_edges
from blurtrack.detect.lines.lawfit import LAW_SAMPLES, fit_law, time_law
from blurtrack.detect.lines.shortfit import fit_short
from blurtrack.detect.params import DetectParams
from blurtrack.testing.streak_frames import quantise, render_streaks

T = np.linspace(0.0, 1.0, 401)
#: Time laws (position along the chord as a fraction of it, at uniform times): constant
#: speed; slow at both ends (a shake turning just outside the exposure); slowing down
#: towards the end; running 15 % past the end and back (a hook).
LAWS = {
    "uniform": T,
    "slow_ends": 0.5 - 0.5 * np.cos(np.pi * T),
    "slowing": np.sin(0.5 * np.pi * T),
    "hook": np.interp(T, [0.0, 0.8, 1.0], [0.0, 1.15, 1.0]),
}


def _profile(s: np.ndarray, a: float, L: float, sigma: float, f: np.ndarray) -> np.ndarray:
    """The exact profile of a dot at ``a + L f(t)``, ``t`` uniform, blurred by ``sigma``."""
    x = a + L * f
    g = np.exp(-0.5 * ((s[:, None] - x[None, :]) / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi))
    return np.trapezoid(g, T, axis=1)


def test_the_time_law_is_the_position_along_the_chord() -> None:
    pts = np.stack([3.0 + 6.0 * T, 2.0 - 8.0 * T], axis=1)  # a 10 px straight line
    straight = time_law(pts)
    assert straight is not None
    np.testing.assert_allclose(straight, np.linspace(0, 1, LAW_SAMPLES), atol=1e-12)
    hook = np.stack([10.0 * LAWS["hook"], 0.3 * np.sin(np.pi * T)], axis=1)
    law = time_law(hook)
    assert law is not None
    assert law[0] == 0.0 and law[-1] == pytest.approx(1.0)
    # The run past the end (its peak at t = 0.8 falls between two of the 33 samples).
    assert law.max() == pytest.approx(1.15, abs=0.015)
    # A dot that barely moves has no chord to project on.
    assert time_law(np.array([[5.0, 5.0], [5.4, 5.3], [5.2, 5.2]])) is None


@pytest.mark.parametrize("name", sorted(LAWS))
def test_the_law_fit_recovers_short_streaks(name: str) -> None:
    s = np.arange(30, dtype=np.float64)
    a_true = np.array([9.3, 11.8, 10.5])
    L_true = np.array([4.0, 6.0, 8.5])
    sigma = np.array([1.3, 1.5, 1.8])
    f = LAWS[name]
    y = np.stack(
        [200 * _profile(s, a, L, g, f) for a, L, g in zip(a_true, L_true, sigma, strict=True)]
    )
    law = np.tile(np.interp(np.linspace(0, 1, LAW_SAMPLES), T, f), (3, 1))
    w = np.ones_like(y)
    a, L, level = fit_law(y, w, sigma, law, a_true - 0.7, L_true + 1.2)
    np.testing.assert_allclose(a, a_true, atol=0.02)
    np.testing.assert_allclose(L, L_true, atol=0.03)
    np.testing.assert_allclose(level, 200 / L_true, rtol=0.01)


def test_a_density_fit_reads_slow_ends_as_a_longer_streak_the_law_fit_does_not() -> None:
    # Negative control: the short fit's density (linear below 5 sigmas) cannot follow the
    # light piling up at both slow ends, and measures the streak too long.
    s = np.arange(30, dtype=np.float64)
    a_true, L_true, sigma = 11.2, 6.0, np.array([1.4])
    y = 200 * _profile(s, a_true, L_true, 1.4, LAWS["slow_ends"])[None]
    w = np.ones_like(y)
    _, L_short, _ = fit_short(y, w, sigma, np.array([a_true]), np.array([L_true]), 6)
    assert L_short[0] - L_true > 0.6
    law = np.interp(np.linspace(0, 1, LAW_SAMPLES), T, LAWS["slow_ends"])[None]
    _, L_law, _ = fit_law(y, w, sigma, law, np.array([a_true]), np.array([L_true]))
    assert abs(L_law[0] - L_true) < 0.02


def test_the_law_fit_is_unbiased_under_noise() -> None:
    rng = np.random.default_rng(7)
    s = np.arange(30, dtype=np.float64)
    n = 200
    clean = 100 * _profile(s, 10.4, 6.0, 1.4, LAWS["slow_ends"])
    y = clean[None] + rng.normal(0.0, 0.5, (n, s.size))  # SNR ~ 30 at the plateau
    law = np.tile(np.interp(np.linspace(0, 1, LAW_SAMPLES), T, LAWS["slow_ends"]), (n, 1))
    a, L, _ = fit_law(y, np.ones_like(y), np.full(n, 1.4), law, np.full(n, 10.0), np.full(n, 7))
    assert abs(np.median(L) - 6.0) < 0.03 and abs(np.median(a) - 10.4) < 0.03
    assert np.percentile(np.abs(L - 6.0), 90) < 0.3


def test_edge_fits_take_the_law_only_where_a_row_has_one() -> None:
    s = np.arange(34, dtype=np.float64)
    f = LAWS["slow_ends"]
    A = np.stack([200 * _profile(s, 12.0, 6.0, 1.4, f), 200 * _profile(s, 13.0, 5.0, 1.4, f)])
    lens = np.array([34, 34])
    sigma = np.array([1.4, 1.4])
    law = np.full((2, LAW_SAMPLES), np.nan)
    law[0] = np.interp(np.linspace(0, 1, LAW_SAMPLES), T, f)
    with_law = fit_edges(A, lens, sigma, law)
    without = fit_edges(A, lens, sigma)
    assert with_law.short.all()
    assert with_law.pos_a[0] == pytest.approx(12.0, abs=0.03)
    assert with_law.pos_b[0] == pytest.approx(18.0, abs=0.03)
    # The row without a law is fitted as before, and that fit is the biased one.
    assert with_law.pos_a[1] == without.pos_a[1] and with_law.pos_b[1] == without.pos_b[1]
    assert without.pos_b[0] - without.pos_a[0] > 6.5


def _frame_and_curves() -> tuple[np.ndarray, list[np.ndarray]]:  # 16-bit, unsaturated
    """Short streaks (6 px) in four directions, half slowing towards both ends and half
    slowing towards their end (a law that is not symmetric: its orientation matters)."""
    curves = []
    rng = np.random.default_rng(3)
    for i in range(8):
        ang = rng.uniform(0, 2 * np.pi)
        d = 6.0 * np.array([np.cos(ang), np.sin(ang)])
        f = LAWS["slow_ends"] if i % 2 else LAWS["slowing"]
        c0 = np.array([20.0 + 30.0 * (i % 4), 20.0 + 30.0 * (i // 4)])
        curves.append(c0[None] + f[:, None] * d[None])
    img = render_streaks((70, 140), curves, flux_per_px=0.5, sigma_px=1.3, noise=0.002)
    return quantise(img, np.uint16), curves


def _measure(img: np.ndarray, curves: list[np.ndarray], with_law: bool, reverse: bool):  # type: ignore[no-untyped-def]
    from blurtrack.detect.context import frame_context
    from blurtrack.detect.image import prepare_frame
    from blurtrack.detect.lines.measure import LineSet, measure_lines

    p = DetectParams()
    prep = prepare_frame(img, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    ctx = frame_context(prep, p)
    comps = ctx.comps
    lines = [c[::-1] if reverse else c for c in curves]
    labels = [comps.labels[round(c[200, 1]), round(c[200, 0])] for c in curves]
    owner = [int(np.flatnonzero(comps.ids == lab)[0]) for lab in labels]
    law = [time_law(c) for c in lines] if with_law else None
    sigma_c = float(np.sqrt(1.3**2 + p.smooth_sigma_px**2))
    ls = LineSet(lines, owner, [False] * len(lines), [False] * len(lines), law)
    return measure_lines(ctx, ls, sigma_c, False)


@pytest.mark.parametrize("reverse", [False, True])
def test_short_streaks_measured_under_their_law_in_either_direction(reverse: bool) -> None:
    img, curves = _frame_and_curves()
    m = _measure(img, curves, True, reverse)
    assert list(m.src) == list(range(len(curves)))
    for k, c in enumerate(curves):
        start, end = (c[-1], c[0]) if reverse else (c[0], c[-1])
        assert np.hypot(*(m.end_a[k] - start)) < 0.2, k
        assert np.hypot(*(m.end_b[k] - end)) < 0.2, k
    # Negative control: without the law, the same lines come out too long or misplaced.
    m0 = _measure(img, curves, False, reverse)
    err = [
        max(np.hypot(*(m0.end_a[k] - c[0])), np.hypot(*(m0.end_b[k] - c[-1])))
        if not reverse
        else max(np.hypot(*(m0.end_a[k] - c[-1])), np.hypot(*(m0.end_b[k] - c[0])))
        for k, c in enumerate(curves)
    ]
    assert max(err) > 0.4


def test_a_long_streak_whose_dot_rests_at_its_start_is_fitted_under_its_law() -> None:
    """A 14 px streak whose dot starts at rest and gathers speed as ``t**3`` (half the
    exposure within 15 % of the chord from the start). Edge fits put the start at the half
    level of the resting spot's peak, 1.5 px outwards; under its law the start is the dot's.
    Negative controls: the same streak where the row may not be fitted whole (saturated or
    crossing: ``law_whole`` false) keeps its edge fits, and a constant-speed streak with a
    law keeps them too (its dot rests nowhere)."""
    s = np.arange(44, dtype=np.float64)
    rest = T**3  # starts at rest
    uniform = T
    A = np.stack([300 * _profile(s, 15.0, 14.0, 1.4, f) for f in (rest, rest, uniform)])
    lens = np.full(3, 44)
    sigma = np.full(3, 1.4)
    law = np.stack([np.interp(np.linspace(0, 1, LAW_SAMPLES), T, f) for f in (rest, rest, uniform)])
    whole = np.array([True, False, True])
    fit = fit_edges(A, lens, sigma, law, whole)
    edges = fit_edges(A, lens, sigma)
    assert not edges.short.any()
    assert edges.pos_a[0] < 15.0 - 1.0  # the edge fit's start: outwards of the resting dot
    assert fit.pos_a[0] == pytest.approx(15.0, abs=0.03)
    assert fit.pos_b[0] == pytest.approx(29.0, abs=0.03)
    assert fit.short[0] and not fit.short[1] and not fit.short[2]
    for k in (1, 2):
        assert fit.pos_a[k] == edges.pos_a[k] and fit.pos_b[k] == edges.pos_b[k]


def test_a_streak_too_long_for_its_laws_samples_keeps_its_edge_fits() -> None:
    """60 px at a 1.4 px sigma: the law's 33 samples lie 1.9 px apart, more than half a
    sigma, and their blurred sum would be lumpy; the resting dot's streak keeps its edge fits."""
    s = np.arange(90, dtype=np.float64)
    A = 300 * _profile(s, 15.0, 60.0, 1.4, T**3)[None]
    law = np.interp(np.linspace(0, 1, LAW_SAMPLES), T, T**3)[None]
    fit = fit_edges(A, np.array([90]), np.array([1.4]), law, np.array([True]))
    edges = fit_edges(A, np.array([90]), np.array([1.4]))
    assert not fit.short[0]
    assert fit.pos_a[0] == edges.pos_a[0] and fit.pos_b[0] == edges.pos_b[0]
