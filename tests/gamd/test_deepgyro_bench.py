"""The no-reference measures of bench/deepgyro_deblur.py (docs/gamd.md, "Real recording:
DeepGyro SHIELD")."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.testing.bench_script import load_bench_script
from gamd.restorer import RestoreOptions


@pytest.fixture(scope="module")
def bench():
    return load_bench_script("deepgyro_deblur")


def _scene(seed: int = 0, size: tuple[int, int] = (96, 160)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.random(size).astype(np.float32), (0, 0), 1.0)
    return np.repeat(g[:, :, None], 3, axis=2)


def test_sharpness_falls_with_blur_and_matches_a_derived_value(bench) -> None:
    img = _scene()
    s0 = bench.sharpness(bench.gray(img))
    blurred = cv2.blur(img, (9, 1))
    s1 = bench.sharpness(bench.gray(blurred))
    assert s1["lap_var"] < 0.5 * s0["lap_var"]
    assert s1["grad_energy"] < 0.5 * s0["grad_energy"]
    # a horizontal ramp of slope a = 0.01: Sobel/8 gives a in x and 0 in y, except in the two
    # edge columns, where the reflected border makes the x gradient 0; the Laplacian is 0 but
    # for ±2a in those two columns (mean 0), so its variance is 2·(2a)²/n
    n = 56
    ramp = np.tile(np.arange(n, dtype=np.float32) * 0.01, (24, 1))
    s = bench.sharpness(ramp)
    assert s["grad_energy"] == pytest.approx(1e-4 * (n - 2) / n, rel=1e-4)
    assert s["lap_var"] == pytest.approx(2 * 0.02**2 / n, rel=1e-4)


def test_measure_frame_gate_and_identity(bench) -> None:
    img = _scene(1)
    h, w = img.shape[:2]
    opts = RestoreOptions(8.0, work_blur_px=8.0, gate_px=(0.3, 1.0), recentre=True)
    still = np.zeros((6, h, w), np.float32)
    res = bench.measure_frame(img, still, {"gamd": img.copy()}, opts, margin=8)
    assert res["gate_closed_fraction"] == 1.0  # no blur: the gate keeps the input
    assert res["gamd"]["identical_to_input_fraction"] == 1.0
    assert res["gamd"]["mean_abs_change_vs_input"] == 0.0
    assert res["working_scale"] == 1.0
    # a uniform 20-px horizontal blur centred on each pixel: gate open, no recentring shift
    heat = np.zeros((6, h, w), np.float32)
    heat[0], heat[2] = -10.0, 10.0
    changed = np.clip(img + 0.1, 0, 1)
    res = bench.measure_frame(img, heat, {"gamd": changed}, opts, margin=8)
    assert res["gate_closed_fraction"] == 0.0
    assert res["working_scale"] == pytest.approx(20.0 / 8.0, rel=1e-3)
    assert res["centre_offset_px_max"] == pytest.approx(0.0, abs=1e-6)
    assert res["gamd"]["identical_to_input_fraction"] < 0.05
    np.testing.assert_allclose(res["_recentred"], img)  # centred blur: nothing resampled
