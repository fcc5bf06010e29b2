"""Template separation of touching streaks (blurtrack.detect.separate) and the artefact filter
(blurtrack.detect.segment.drop_artefacts), on exactly rendered frames."""

from __future__ import annotations

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
