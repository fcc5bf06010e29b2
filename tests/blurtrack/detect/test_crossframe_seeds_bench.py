"""The truth-free correction of bench/crossframe_seeds.py (docs/journal/detection.md, "Session
2026-12-04, second"): carried midpoints mapped onto a frame's own detections by the
displacement most of them agree with, then affine fits to nearest-neighbour pairs."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.testing.bench_script import load_bench_script


@pytest.fixture(scope="module")
def bench():
    return load_bench_script("crossframe_seeds")


def _grid(rng: np.random.Generator) -> np.ndarray:
    """A jittered dot grid, 50 px spacing, over a 1280 x 720 frame."""
    gx, gy = np.meshgrid(np.arange(40, 1240, 50.0), np.arange(40, 700, 50.0))
    return np.c_[gx.ravel(), gy.ravel()] + rng.uniform(-12, 12, (gx.size, 2))


def test_correction_recovers_an_affine_map_from_the_frames_own_detections(bench) -> None:
    rng = np.random.default_rng(3)
    dots = _grid(rng)
    # The carried points are off by a smooth map: 14 px of shift, 2 % of scale, 0.5 deg.
    c, s = 1.02 * np.cos(0.009), 1.02 * np.sin(0.009)
    A = np.array([[c, -s], [s, c]])
    truth = dots @ A.T + np.array([14.0, -9.0])
    # Frame k found 60 % of the dots (0.1 px noise) and 20 spurious ones.
    found = rng.random(len(dots)) < 0.6
    own = truth[found] + rng.normal(0, 0.1, (int(found.sum()), 2))
    own = np.vstack([own, rng.uniform([0, 0], [1280, 720], (20, 2))])
    raw = np.linalg.norm(dots - truth, axis=1)
    q = bench.correct(dots, own)
    assert q is not None
    err = np.linalg.norm(q - truth, axis=1)
    # Derived truth: every dot, found or not, lands within the detections' noise.
    assert np.median(err) < 0.1
    assert np.max(err) < 0.5
    # Negative control: uncorrected, the carried points are ~15 px off.
    assert np.median(raw) > 10.0


def test_correction_refuses_too_few_detections(bench) -> None:
    rng = np.random.default_rng(4)
    dots = _grid(rng)
    assert bench.correct(dots, dots[:3] + 5.0) is None
    assert bench.correct(dots[:3], dots) is None
