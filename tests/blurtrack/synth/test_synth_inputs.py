"""Photometry, gyro sources, shake reader, perturbations and photograph handling."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.errors import SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.synth import photometry as ph
from blurtrack.synth.images import camera_for_size, fit_to_size, list_images, load_image, split_of
from blurtrack.synth.motion import SyntheticSource, TraceSource, open_source
from blurtrack.synth.perturb import Perturbation

DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data"
SHAKE = DATA / "real" / "gyrodeblurnet-shake"


def test_srgb_round_trips_every_8bit_code() -> None:
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16)
    img = np.dstack([codes] * 3)
    np.testing.assert_array_equal(ph.encode_srgb8(ph.decode_srgb8(img)), img)
    assert ph.decode_srgb8(np.array([128], np.uint8))[0] == pytest.approx(0.2158605, abs=1e-6)


def test_linear_average_is_brighter_than_srgb_average() -> None:
    # Half black, half white averaged in light is 0.5 linear = code 188, not 128.
    lin = ph.decode_srgb8(np.array([[0, 255]], np.uint8)).mean()
    assert ph.encode_srgb8(np.array([lin]))[0] == 188


def test_noise_variance_follows_poisson_gaussian_model() -> None:
    rng = np.random.default_rng(0)
    x = np.full((400, 400, 1), 0.3, np.float32)
    y = ph.add_noise(x, 0.01, 0.02, rng)
    assert y.var() == pytest.approx(0.01 * 0.3 + 0.02**2, rel=0.03)
    assert abs(y.mean() - 0.3) < 1e-3
    assert ph.add_noise(x, 0, 0, rng) is not x and np.all(ph.add_noise(x, 0, 0, rng) == x)


def test_saturation_expansion_and_photometry_validation() -> None:
    lin = np.array([[[0.5, 0.2, 0.1], [1.0, 1.0, 0.5]]], np.float32)
    out = ph.expand_saturation(lin, 0.9, 4.0)
    np.testing.assert_allclose(out[0, 0], lin[0, 0])
    np.testing.assert_allclose(out[0, 1], 4.0 * lin[0, 1])
    for bad in (
        {"saturation_gain": 0.5},
        {"noise_shot": -1},
        {"jpeg_quality": 101},
        {"saturation_threshold": 1.0},
        {"linear": False, "noise_read": 0.01},
    ):
        with pytest.raises(SynthesisError):
            ph.Photometry(**bad)
    img = (np.random.default_rng(1).random((32, 48, 3)) * 255).astype(np.uint8)
    jp = ph.jpeg_roundtrip(img, 50)
    assert jp.shape == img.shape and not np.array_equal(jp, img)


@pytest.mark.skipif(not SHAKE.is_dir(), reason="../shared/data/real/gyrodeblurnet-shake absent")
def test_real_shake_segments_avoid_the_dropout() -> None:
    src = open_source(str(SHAKE))
    assert isinstance(src, TraceSource) and not src.own_imu
    assert 180 < src.trace.t_s[-1] < 190
    assert not src.trace.covers(src.trace.t_s[0], src.trace.t_s[-1])  # the dropout
    rng = np.random.default_rng(0)
    for _ in range(50):
        seg = src.segment(rng, 0.05, 0.02)
        seg.trace.check_coverage(seg.frame_t_s - 0.02, seg.frame_t_s + 0.07)


def test_segments_are_seeded_and_skip_gaps() -> None:
    t = np.concatenate([np.arange(0, 1, 0.005), np.arange(1.2, 2.0, 0.005)])
    src = TraceSource(GyroTrace(t, np.ones((t.size, 3))), "shake", "x", own_imu=False)
    a = [src.segment(np.random.default_rng(7), 0.1, 0.01).frame_t_s for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(3)
    for _ in range(100):
        s = src.segment(rng, 0.1, 0.01)
        assert not (s.frame_t_s - 0.01 < 1.2 and s.frame_t_s + 0.11 > 0.995)
    with pytest.raises(SynthesisError, match="shorter"):
        src.segment(rng, 5.0, 0.01)


def test_synthetic_motion_has_requested_rms() -> None:
    src = SyntheticSource(0.6, n_tones=12)
    seg = src.segment(np.random.default_rng(2), 3.0, 0.0)
    rms = np.sqrt(np.mean(seg.trace.omega_radps**2, axis=0))
    assert rms[:2] == pytest.approx([0.6, 0.6], rel=0.25)
    assert rms[2] == pytest.approx(0.3, rel=0.25)
    with pytest.raises(SynthesisError):
        open_source("synthetic:abc")


def test_perturbation_changes_heat_maps_by_the_expected_amount() -> None:
    cam = Camera((64, 48), (60.0, 60.0, 31.5, 23.5))
    t = np.arange(0, 1, 0.005)
    trace = GyroTrace(t, np.tile([0.0, 1.0, 0.0], (t.size, 1)) * (1 + t[:, None]))
    calib = Calibration(cam)
    zero = Perturbation()
    c2, t2, drawn = zero.apply(calib, trace, np.random.default_rng(0))
    assert not zero.active and drawn["timeshift_s"] == 0
    h0, _ = BlurModel(calib, trace).heat_maps(0.3, 0.02, t_ref_s=0.31)
    np.testing.assert_array_equal(BlurModel(c2, t2).heat_maps(0.3, 0.02, t_ref_s=0.31)[0], h0)
    p = Perturbation.parse("timeshift_ms=5")
    c3, t3, drawn = p.apply(calib, trace, np.random.default_rng(1))
    h3, _ = BlurModel(c3, t3).heat_maps(0.3, 0.02, t_ref_s=0.31)
    # A time shift dt changes q(1) - q(0) by about f * (dω/dt) * dt * exposure.
    change = np.abs((h3[2] - h3[0]) - (h0[2] - h0[0])).mean()
    assert change == pytest.approx(60 * 1.0 * abs(drawn["timeshift_s"]) * 0.02, rel=0.2)
    for bad in ("timeshift=1", "focal_rel=x", "gyro_noise=-1"):
        with pytest.raises(SynthesisError):
            Perturbation.parse(bad)


def test_images_listing_split_fit_and_camera(tmp_path: Path) -> None:
    for rel in ("train/a.png", "test/b.jpg", "val/c.png", ".hidden/d.png", "train/e.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tmp_path / rel), np.zeros((30, 40, 3), np.uint8)) if rel.endswith(
            ("png", "jpg")
        ) else (tmp_path / rel).write_text("x")
    assert list_images(tmp_path) == ["test/b.jpg", "train/a.png", "val/c.png"]
    assert [split_of(r) for r in list_images(tmp_path)] == ["test", "train", "train"]
    img = load_image(tmp_path, "train/a.png")
    out, info = fit_to_size(img, 64, 32, np.random.default_rng(0))
    assert out.shape == (32, 64, 3) and info["scale"] == pytest.approx(1.6)
    with pytest.raises(SynthesisError, match="upscaling"):
        fit_to_size(img, 64, 32, np.random.default_rng(0), upscale=False)
    with pytest.raises(SynthesisError, match="inside"):
        load_image(tmp_path, "../x.png")
    cam = Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5))
    sq = camera_for_size(cam, 360, 360)  # cover 720 rows -> scale 0.5, crop the sides
    assert sq.intrinsics == pytest.approx((500.0, 500.0, 179.5, 179.5))
