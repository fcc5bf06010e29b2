"""The renderer: energy, centroids, rolling shutter, streak shape and the sensor model."""

from __future__ import annotations

import numpy as np
import pytest

from rigs.sim.dots import dot_pixels
from rigs.sim.preset import get_preset
from rigs.sim.render import expose, render_points, splat
from rigs.sim.rig import SimRig

SMALL = dict(width=200, height=150, focal_px=160.0, dot_cols=5, dot_rows=4, motion="synthetic")


def test_splat_conserves_energy_and_centroid() -> None:
    rng = np.random.default_rng(1)
    for _ in range(5):
        u, v = rng.uniform(20, 60, 2)
        out = np.zeros((80, 90))
        splat(out, np.array([u]), np.array([v]), 1.4, lambda r, s: np.full(r.shape, 7.0))
        assert out.sum() == pytest.approx(7.0, rel=5e-4)  # tails beyond 3.5 sigma cut
        ys, xs = np.mgrid[:80, :90]
        assert (out * xs).sum() / out.sum() == pytest.approx(u, abs=1e-3)
        assert (out * ys).sum() / out.sum() == pytest.approx(v, abs=1e-3)


def test_splat_clips_at_borders_without_wrapping() -> None:
    out = np.zeros((40, 50))
    splat(out, np.array([-1.0, 49.4]), np.array([20.0, 38.8]), 1.5, lambda r, s: np.ones(r.shape))
    assert 0.1 < out.sum() < 1.0  # parts of both patches fall outside
    assert out[:, 10:40].sum() == 0.0 and out[:10].sum() == 0.0


def brute_force(rig: SimRig, t_f: float, steps: int = 20000) -> np.ndarray:
    """Reference: equal 1-µs-class time steps, each gated by its midpoint per pixel row."""
    p, cam = rig.preset, rig.camera
    J = rig.dots_world.shape[0]
    t = t_f + (np.arange(steps) + 0.5) * (cam.readout_s + p.exposure_s) / steps
    dt = (cam.readout_s + p.exposure_s) / steps
    pos = dot_pixels(rig.motion, cam, rig.dots_world, np.repeat(t, J), np.tile(np.arange(J), steps))
    ts = np.repeat(t, J)
    out = np.zeros((cam.height, cam.width))

    def gate(rows, sel):
        r0 = t_f + cam.readout_s * rows / cam.height
        tt = ts[sel][:, None]
        return p.dot_flux_eps * dt * ((tt >= r0) & (tt < r0 + p.exposure_s))

    splat(out, pos[:, 0], pos[:, 1], p.dot_sigma_px, gate)
    return out


@pytest.mark.parametrize("readout_s", [0.0, 0.025])
def test_render_matches_brute_force(readout_s: float) -> None:
    preset = get_preset("realistic").replace(
        **SMALL, synthetic_rms_radps=(1.5, 1.5, 1.0), readout_s=readout_s
    )
    rig = SimRig(preset, 3, 2)
    t_f = rig.frame_times_ns[1] * 1e-9
    fast = rig.render_electrons(t_f)
    ref = brute_force(rig, t_f)
    assert rig.streaks(t_f).length_px.max() > 5  # real streaks (f = 160 px), not dots
    assert np.abs(fast - ref).max() < 0.01 * ref.max()
    assert fast.sum() == pytest.approx(ref.sum(), rel=2e-3)


def test_streak_energy_lies_along_truth_centerline() -> None:
    preset = get_preset("realistic").replace(motion="synthetic")
    rig = SimRig(preset, 9, 2)
    t_f = rig.frame_times_ns[1] * 1e-9
    e = rig.render_electrons(t_f)
    s = rig.streaks(t_f)
    H, W = e.shape
    sigma = preset.dot_sigma_px
    near_any = np.zeros((H, W), bool)
    ys, xs = np.mgrid[:H, :W]
    checked = 0
    for j in np.flatnonzero(s.visible):
        path = s.path[j]
        x0, y0 = np.floor(path.min(0) - 4 * sigma).astype(int)
        x1, y1 = np.ceil(path.max(0) + 4 * sigma).astype(int)
        win = (slice(max(y0, 0), y1 + 1), slice(max(x0, 0), x1 + 1))
        px = np.stack([xs[win].ravel(), ys[win].ravel()], 1).astype(float)
        d = np.min(np.linalg.norm(px[:, None, :] - path[None, ::2, :], axis=2), axis=1)
        mask = (d <= 3.5 * sigma).reshape(xs[win].shape)
        near_any[win] |= mask
        if not s.inside[j]:
            continue
        # A dot's light is collected while its row exposes: t_end - t_start (the rolling
        # shutter stretches or shrinks it by the vertical speed over the readout rate).
        per_dot = preset.dot_flux_eps * (s.t_end_s[j] - s.t_start_s[j])
        assert e[win][mask].sum() == pytest.approx(per_dot, rel=0.005)
        checked += 1
    assert checked > 100
    # Almost nothing lands away from the centre lines.
    assert e[~near_any].sum() < 0.01 * e.sum()


def test_sharp_frame_peaks_at_reference_positions() -> None:
    preset = get_preset("clean").replace(**SMALL)
    rig = SimRig(preset, 2, 2)
    t_ref = rig.reference_time(rig.frame_times_ns[0] * 1e-9)
    e = rig.sharp_electrons(t_ref)
    ref = rig.streaks(rig.frame_times_ns[0] * 1e-9).ref
    ys, xs = np.mgrid[:15, :15]
    checked = 0
    for u, v in ref:
        if 8 < u < preset.width - 9 and 8 < v < preset.height - 9:
            iu, iv = round(u), round(v)
            patch = e[iv - 7 : iv + 8, iu - 7 : iu + 8]
            assert (patch * xs).sum() / patch.sum() + iu - 7 == pytest.approx(u, abs=1e-3)
            assert (patch * ys).sum() / patch.sum() + iv - 7 == pytest.approx(v, abs=1e-3)
            checked += 1
    assert checked >= 6
    img = rig.render_sharp(t_ref)
    assert img.dtype == np.uint8 and img.max() == 255  # a whole exposure in one spot


def test_render_points_energy() -> None:
    e = render_points((60, 80), np.array([[30.2, 20.7], [50.5, 40.1]]), 100.0, 1.2)
    assert e.sum() == pytest.approx(200.0, rel=5e-4)


def test_expose_noise_statistics_and_saturation() -> None:
    rng = np.random.default_rng(0)
    sig = np.full((400, 400), 3000.0)
    img = expose(sig, 1000.0, 10000.0, 20.0, True, 16, rng).astype(float)
    gain = 65535 / 10000.0
    assert img.mean() / gain == pytest.approx(4000.0, rel=2e-3)
    assert img.var() / gain**2 == pytest.approx(4000.0 + 400.0, rel=0.03)
    low = expose(np.full((300, 300), 3.0), 0.0, 10000.0, 0.0, True, 16, rng).astype(float)
    assert low.mean() / gain == pytest.approx(3.0, rel=0.02)  # exact Poisson branch
    assert low.var() / gain**2 == pytest.approx(3.0, rel=0.05)
    sat = expose(np.full((4, 4), 5e4), 0.0, 10000.0, 5.0, True, 8, rng)
    assert sat.dtype == np.uint8 and np.all(sat == 255)
    clean = expose(np.array([[0.0, 5000.0]]), 0.0, 10000.0, 0.0, False, 8, None)
    assert clean.tolist() == [[0, 128]]


def test_sixteen_bit_frames() -> None:
    rig = SimRig(get_preset("clean").replace(bit_depth=16, **SMALL), 1, 1)
    img = rig.render_frame(rig.frame_times_ns[0] * 1e-9)
    assert img.dtype == np.uint16 and img.max() > 255


def test_ambient_vignetting() -> None:
    from rigs.sim.render import ambient_map

    a = ambient_map(101, 51, 1000.0, 0.3)
    assert a[25, 50] == pytest.approx(1000.0)
    assert a[0, 0] == pytest.approx(700.0) and a[50, 100] == pytest.approx(700.0)
    assert a[25, 0] > a[0, 0] and a[25, 0] < a[25, 50]


def test_blurred_frame_is_the_sharp_frame_averaged_along_the_model_trajectories() -> None:
    # DESIGN's heat-map definition: B(x) = mean over the row's exposure of S(warp(x, t, t_ref)).
    import cv2

    from blurtrack.geometry.blur_model import BlurModel
    from blurtrack.geometry.gyro import GyroTrace

    preset = get_preset("realistic").replace(
        width=160,
        height=120,
        focal_px=400.0,
        dot_cols=4,
        dot_rows=3,
        motion="synthetic",
        dot_sigma_px=2.0,
        gyro_noise_radps=0.0,
        gyro_bias_radps=0.0,
        gyro_scale_error=0.0,
        imu_rate_hz=1000.0,
        synthetic_rms_radps=(0.6, 0.6, 0.6),
    )
    rig = SimRig(preset, 6, 2)
    t_f = rig.frame_times_ns[1] * 1e-9
    t_ref = rig.reference_time(t_f)
    sharp = rig.sharp_electrons(t_ref).astype(np.float32)
    blurred = rig.render_electrons(t_f)
    t_imu = rig.gyro_times_ns() * 1e-9
    model = BlurModel(rig.calibration, GyroTrace(t_imu, rig.sample_gyro(t_imu)))
    H, W = blurred.shape
    ys, xs = np.mgrid[:H, :W].astype(float)
    px = np.stack([xs.ravel(), ys.ravel()], 1)
    row_t0 = rig.camera.row_start_s(t_f, ys.ravel())
    n = 60
    synth = np.zeros(H * W)
    for k in range(n):
        t = row_t0 + (k + 0.5) / n * preset.exposure_s
        q = model.warp(px, t, np.full(px.shape[0], t_ref)).astype(np.float32)
        synth += (
            cv2.remap(
                sharp,
                q[:, 0].reshape(H, W),
                q[:, 1].reshape(H, W),
                cv2.INTER_LINEAR,
                borderValue=0.0,
            ).ravel()
            / n
        )
    # Away from the borders (the sharp frame lacks light from beyond them; bilinear sampling
    # of the sharp frame smooths by a few % of the peak):
    inner = (slice(15, H - 15), slice(15, W - 15))
    synth = synth.reshape(H, W)[inner]
    ref = blurred[inner]
    assert rig.streaks(t_f).length_px.max() > 4
    assert np.abs(synth - ref).max() < 0.05 * ref.max()
    assert synth.sum() == pytest.approx(ref.sum(), rel=0.005)


def test_arc_length_slots_tile_each_window_with_short_moves() -> None:
    from rigs.sim.render import arc_length_slots

    rng = np.random.default_rng(3)
    J, M = 7, 64
    t = np.sort(rng.uniform(0, 1, (J, 1)), axis=0) + np.linspace(0, 0.02, M + 1)[None, :]
    # wiggly paths, one standing still
    speed = rng.uniform(0, 3000, (J, 1)) * np.sin(np.linspace(0, 9, M + 1))[None, :] ** 2
    speed[2] = 0.0
    step = np.diff(t, axis=1) * speed[:, 1:]
    ang = rng.uniform(0, 6.3, (J, M))
    p = (
        np.concatenate(
            [
                np.zeros((J, 1, 2)),
                np.cumsum(np.stack([step * np.cos(ang), step * np.sin(ang)], -1), axis=1),
            ],
            axis=1,
        )
        + 100
    )
    dot, lo, hi = arc_length_slots(t, p, 0.25)
    for j in range(J):
        sel = dot == j
        assert sel.sum() >= 4
        a, b = lo[sel], hi[sel]
        assert a[0] == pytest.approx(t[j, 0], abs=1e-12)
        assert b[-1] == pytest.approx(t[j, -1], abs=1e-12)
        np.testing.assert_allclose(a[1:], b[:-1], atol=0)
        assert np.all(b > a)
        # positions along the piecewise-linear path move <= 0.25 px within any slot
        fine = np.linspace(t[j, 0], t[j, -1], 20001)
        xy = np.stack([np.interp(fine, t[j], p[j, :, k]) for k in (0, 1)], 1)
        which = np.clip(np.searchsorted(b, fine, side="left"), 0, a.size - 1)
        for k in np.unique(which)[::7]:
            seg = xy[which == k]
            if len(seg) > 1:
                assert np.linalg.norm(seg - seg[0], axis=1).max() <= 0.25 * 1.02
