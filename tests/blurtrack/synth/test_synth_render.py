"""Exactness of the blur renderer: B(x) = mean_k S(x + q_x(τ_k)) against the core model."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blurtrack.errors import SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.synth.paper import paper_model, render_paper
from blurtrack.synth.render import (
    NodeGrid,
    RenderSettings,
    plan_samples,
    render_blur,
    source_positions,
)

RADTAN = (-0.12, 0.03, 0.001, -0.0015)


def shake_trace(seed: int = 0, scale: float = 1.0) -> GyroTrace:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 1.0, 0.005)
    f = rng.uniform(1, 8, 3)
    w = scale * np.stack(
        [
            0.8 * np.sin(2 * np.pi * f[0] * t),
            0.9 * np.cos(2 * np.pi * f[1] * t),
            0.4 * np.sin(2 * np.pi * f[2] * t + 1.0),
        ],
        axis=1,
    )
    return GyroTrace(t, w)


def make_model(
    readout: float = 0.0,
    dist: bool = False,
    size=(160, 96),
    f: float = 150.0,
    trace: GyroTrace | None = None,
) -> BlurModel:
    W, H = size
    cam = Camera(
        (W, H),
        (f, f * 1.01, (W - 1) / 2 + 3, (H - 1) / 2 - 2),
        readout_s=readout,
        distortion_model="radtan" if dist else "none",
        distortion_coeffs=RADTAN if dist else (),
    )
    R = cv2.Rodrigues(np.array([0.1, -0.2, 0.05]))[0]
    return BlurModel(Calibration(cam, R_cam_imu=R), trace or shake_trace())


def ramp(model: BlurModel) -> np.ndarray:
    W, H = model.camera.resolution
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    return np.dstack([u, v, np.ones_like(u)])


@pytest.mark.parametrize(
    ("readout", "dist", "path"),
    [
        (0.0, False, "homography"),
        (0.03, False, "remap"),
        (0.03, True, "remap"),
        (0.0, True, "remap"),
    ],
)
def test_ramp_blur_is_mean_trajectory(readout: float, dist: bool, path: str) -> None:
    # Bilinear interpolation reproduces a linear image exactly, so B(x) - x is the mean of
    # q_x over the samples: compare with the core's BlurModel.warp pixel by pixel.
    m = make_model(readout, dist)
    res = render_blur(ramp(m), m, 0.3, 0.03)
    assert res.path == path
    t_ref = m.default_reference_time(0.3, 0.03)
    rng = np.random.default_rng(1)
    W, H = m.camera.resolution
    px = np.stack([rng.integers(0, W, 40), rng.integers(0, H, 40)], axis=1).astype(float)
    px = px[res.valid[px[:, 1].astype(int), px[:, 0].astype(int)]]
    assert len(px) > 20
    t = m.camera.row_start_s(0.3, px[:, 1])[:, None] + 0.03 * res.tau[None, :]
    n = res.tau.size
    track = m.warp(np.repeat(px, n, axis=0), t.reshape(-1), np.full(t.size, t_ref))
    mean = np.einsum("pkc,k->pc", track.reshape(-1, n, 2), res.weights)
    got = res.blur[px[:, 1].astype(int), px[:, 0].astype(int), :2]
    np.testing.assert_allclose(got, mean, atol=0.01)
    np.testing.assert_allclose(res.blur[..., 2], 1.0, atol=1e-5)


def test_samples_move_at_most_half_a_pixel() -> None:
    m = make_model(0.02, trace=shake_trace(3, 3.0))
    st = RenderSettings()
    t_ref = m.default_reference_time(0.2, 0.04)
    plan = plan_samples(m, 0.2, 0.04, t_ref, st)
    uniform = plan_samples(m, 0.2, 0.04, t_ref, RenderSettings(adaptive=False))
    tau = plan.tau
    assert plan.step_px <= 0.5 and tau.size > 20 and tau.size <= uniform.tau.size
    assert plan.weights.sum() == pytest.approx(1.0) and np.all(np.diff(tau) > 0)
    np.testing.assert_allclose(uniform.weights, 1 / uniform.tau.size)
    W, H = m.camera.resolution
    u, v = np.linspace(0, W - 1, 23), np.linspace(0, H - 1, 17)
    mx, my = source_positions(m, 0.2, 0.04, t_ref, u, v, tau)
    assert np.max(np.hypot(np.diff(mx, axis=0), np.diff(my, axis=0))) <= 0.5 + 1e-3


def test_node_grid_upsampling_is_exact_to_the_border() -> None:
    for W, H, g in [(160, 96, 16), (481, 321, 16), (37, 23, 8)]:
        grid = NodeGrid.build(W, H, g)
        assert grid.u[0] <= 0 and grid.u[-1] >= W - 1 and grid.v[0] <= 0 and grid.v[-1] >= H - 1
        nodes = (0.3 * grid.u[None, :] - 0.7 * grid.v[:, None] + 5).astype(np.float32)
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        np.testing.assert_allclose(grid.upsample(nodes), 0.3 * u - 0.7 * v + 5, atol=2e-3)


def dot_image(m: BlurModel, p: np.ndarray, sigma: float = 0.8) -> np.ndarray:
    W, H = m.camera.resolution
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    return np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / (2 * sigma**2)).astype(np.float32)


def half_max_ends(img: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    """Where the profile along the segment a -> b (extended 6 px) falls to half its plateau."""
    d = (b - a) / np.linalg.norm(b - a)
    s = np.arange(-6.0, np.linalg.norm(b - a) + 6.0, 0.02)
    pts = a[None, :] + s[:, None] * d[None, :]
    prof = cv2.remap(
        img,
        pts[:, 0].astype(np.float32)[None],
        pts[:, 1].astype(np.float32)[None],
        cv2.INTER_LINEAR,
    )[0]
    half = 0.5 * np.median(prof[(s > 3) & (s < s[-1] - 9)])
    above = np.flatnonzero(prof >= half)
    i0, i1 = above[0], above[-1]
    s0 = np.interp(half, [prof[i0 - 1], prof[i0]], [s[i0 - 1], s[i0]])
    s1 = np.interp(half, [prof[i1 + 1], prof[i1]], [s[i1 + 1], s[i1]])
    return a + s0 * d, a + s1 * d


@pytest.mark.parametrize("readout", [0.0, 0.02])
def test_blurred_dot_ends_where_model_and_heat_maps_say(readout: float) -> None:
    # Constant ω: straight, uniform streaks, so the half-maximum points are the endpoints.
    t = np.arange(0.0, 1.0, 0.005)
    trace = GyroTrace(t, np.tile([0.25, -0.55, 0.05], (t.size, 1)))
    m = make_model(readout, size=(200, 120), f=300.0, trace=trace)
    frame_t, exposure = 0.3, 0.06
    t_ref = m.default_reference_time(frame_t, exposure)
    p = np.array([95.3, 61.7])
    res = render_blur(dot_image(m, p), m, frame_t, exposure, t_ref)
    start, end, _, _ = m.streak_endpoints(p[None], t_ref, frame_t, exposure)
    assert np.linalg.norm(end - start) > 8
    got0, got1 = half_max_ends(res.blur, start[0], end[0])
    assert np.linalg.norm(got0 - start[0]) < 0.2
    assert np.linalg.norm(got1 - end[0]) < 0.2
    # The heat map at the streak's ends points back to the dot: x + q(0) = p at the start.
    heat, _ = m.heat_maps(frame_t, exposure, 16, t_ref, stride=1)
    for x, ch in ((start[0], 0), (end[0], 2)):
        q = [
            cv2.remap(heat[c], np.float32([[x[0]]]), np.float32([[x[1]]]), cv2.INTER_LINEAR)[0, 0]
            for c in (ch, ch + 1)
        ]
        np.testing.assert_allclose(x + q, p, atol=0.05)


def test_constant_border_and_validity_mask() -> None:
    m = make_model(0.01, trace=shake_trace(5, 2.0))
    ones = np.ones((96, 160), np.float32)
    res = render_blur(ones, m, 0.3, 0.03, settings=RenderSettings(border="constant"))
    assert 0.5 < res.valid.mean() < 1.0
    np.testing.assert_allclose(res.blur[res.valid], 1.0, atol=1e-4)
    # Invalid pixels read black for part of the exposure (a few read it only at the edge pixel
    # itself, within remap's 1/32-px coordinate resolution).
    assert np.mean(res.blur[~res.valid] < 1.0 - 1e-4) > 0.95
    rr = render_blur(ones, m, 0.3, 0.03)  # reflect: the image stays 1 everywhere
    np.testing.assert_allclose(rr.blur, 1.0, atol=1e-5)


def test_refuses_wrong_image_and_excess_blur() -> None:
    m = make_model()
    with pytest.raises(SynthesisError, match="float32"):
        render_blur(np.zeros((96, 160, 3), np.uint8), m, 0.3, 0.03)
    with pytest.raises(SynthesisError, match="samples"):
        render_blur(
            np.zeros((96, 160), np.float32), m, 0.3, 0.03, settings=RenderSettings(max_samples=3)
        )


def test_paper_mode_follows_small_angle_four_corner_model() -> None:
    m = make_model(0.02, dist=False, trace=shake_trace(2, 2.0))
    H = m.camera.height
    calib = m.calib
    res = render_paper(ramp(m), calib, m.gyro, 0.3, 0.03)
    assert res.path == "paper"
    pm = paper_model(calib, m.gyro)
    t0 = float(m.camera.row_start_s(0.3, (H - 1) / 2))
    t_ref = t0 + 0.015
    px = np.array([[20.0, 30.0], [80.0, 48.0], [140.0, 70.0]])
    # Sub-steps are equally weighted within a gyro interval and intervals by duration: the
    # paper's average of the ramp is a weighted mean of its four-corner homography warps,
    # which for a pinhole camera equal the small-angle model's point warps.
    times = t0 + 0.03 * res.tau
    bounds = np.concatenate(
        [[t0], np.sort(m.gyro.t_s[(m.gyro.t_s > t0) & (m.gyro.t_s < t0 + 0.03)]), [t0 + 0.03]]
    )
    j = np.searchsorted(bounds, times) - 1
    counts = np.bincount(j, minlength=bounds.size - 1)
    wts = np.diff(bounds)[j] / counts[j] / 0.03
    for x in px:
        track = pm.warp(np.tile(x, (times.size, 1)), times, np.full(times.size, t_ref))
        np.testing.assert_allclose(
            res.blur[int(x[1]), int(x[0]), :2], (wts[:, None] * track).sum(0), atol=0.02
        )
    exact = render_blur(ramp(m), m, 0.3, 0.03)
    # The paper ignores the rolling shutter: rows away from the centre differ clearly.
    assert np.abs(exact.blur[5, 80, :2] - res.blur[5, 80, :2]).max() > 0.2


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    W=st.integers(2, 300),
    H=st.integers(2, 200),
    g=st.integers(2, 40),
    a=st.floats(-3, 3),
    b=st.floats(-3, 3),
)
def test_node_grid_property(W: int, H: int, g: int, a: float, b: float) -> None:
    grid = NodeGrid.build(W, H, g)
    assert grid.u[0] <= 0 and grid.u[-1] >= W - 1 and grid.v[0] <= 0 and grid.v[-1] >= H - 1
    assert np.all(np.diff(grid.u) <= g + 1e-9) and np.all(np.diff(grid.v) <= g + 1e-9)
    nodes = (a * grid.u[None, :] + b * grid.v[:, None]).astype(np.float32)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    want = a * u + b * v
    np.testing.assert_allclose(grid.upsample(nodes), want, atol=1e-3 + 2e-6 * np.abs(want).max())


@settings(max_examples=30, deadline=None, derandomize=True)
@given(
    W=st.integers(2, 120),
    H=st.integers(2, 90),
    g=st.integers(2, 20),
    y0=st.integers(0, 89),
    rows=st.integers(1, 90),
)
def test_node_grid_band_equals_full_upsampling(W: int, H: int, g: int, y0: int, rows: int) -> None:
    # The renderer upsamples the coordinate maps band by band: the same values (up to float32
    # rounding of OpenCV's scale factors).
    y0, rows = min(y0, H - 1), min(rows, H - min(y0, H - 1))
    grid = NodeGrid.build(W, H, g)
    nodes = np.random.default_rng(W * H + g).random((grid.v.size, grid.u.size, 2))
    nodes = nodes.astype(np.float32)
    canvas = np.full((rows + 3 * g) * grid.u.size * g * 2, np.nan, np.float32)
    band = grid.upsample_rows(nodes, y0, rows, canvas)
    np.testing.assert_allclose(band, grid.upsample(nodes)[y0 : y0 + rows], rtol=0, atol=1e-6)
    assert np.shares_memory(band, canvas)  # the buffer was big enough to be used
