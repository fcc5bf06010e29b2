"""bench/natural_negatives.py's shaken night exposures: the kernel of a real hand shake and the
exposure built from it, against what the rotation rates imply."""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.testing.bench_script import load_bench_script


def _trace(omega_radps: tuple[float, float, float]) -> GyroTrace:
    t = np.arange(0.0, 1.0, 0.005)
    return GyroTrace(t, np.tile(np.asarray(omega_radps, float), (t.size, 1)))


def test_a_steady_pan_draws_a_line_as_long_as_its_angle() -> None:
    bench = load_bench_script("natural_negatives")
    # 0.3 rad/s about y for 1/15 s at 520 px: 10.4 px along x, none along y.
    k = bench.shake_kernel(_trace((0.0, 0.3, 0.0)), 0.1, 1.0 / 15.0, 520.0)
    assert np.isclose(k.sum(), 1.0)
    rows, cols = np.nonzero(k > 1e-9)
    assert rows.max() - rows.min() <= 1
    assert 10.0 <= cols.max() - cols.min() <= 12.0
    # Uniform in time: the light per column is flat along the line.
    per_col = k.sum(axis=0)[cols.min() + 1 : cols.max() - 1]
    assert per_col.std() < 0.1 * per_col.mean()
    # A roll about the optical axis moves the image centre not: a single pixel.
    still = bench.shake_kernel(_trace((0.0, 0.0, 2.0)), 0.1, 1.0 / 15.0, 520.0)
    assert np.count_nonzero(still > 1e-9) == 1


def test_the_shaken_exposure_keeps_light_and_blows_out_the_brightest() -> None:
    bench = load_bench_script("natural_negatives")
    img = np.zeros((40, 60, 3), np.uint8)
    img[18:22, 28:32] = 200
    k = bench.shake_kernel(_trace((0.0, 0.3, 0.0)), 0.1, 1.0 / 15.0, 520.0)
    dim = bench.shaken(img, k, 1.0, 0.25, 0)
    bright = bench.shaken(img, k, 3.0, 4.0, 0)
    assert dim.shape == img.shape and dim.dtype == np.uint8
    # The square is drawn out along x by the line, not along y.
    lit = dim[..., 0] > 40
    ys, xs = np.nonzero(lit)
    assert xs.max() - xs.min() > ys.max() - ys.min() + 6
    # The night exposure leaves the dark ground dark; a lit window wider than the line blows
    # out (a small light, spread over the line, need not).
    assert np.median(bright) < 20
    window = np.zeros_like(img)
    window[12:28, 16:44] = 250
    assert bench.shaken(window, k, 3.0, 4.0, 0)[20, 30].min() == 255
    assert bench.shaken(window, k, 1.0, 0.25, 0)[20, 30].max() < 255
