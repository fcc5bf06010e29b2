"""Real-optics effects of the simulator, and detection on them."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect import detect_frame
from rigs.sim.errors import SimError
from rigs.sim.optics import Optics, bloom, demosaic_and_encode, field_blur, mosaic, speckle
from rigs.sim.preset import get_preset
from rigs.sim.rig import SimRig


def test_speckle_keeps_the_mean_and_has_its_contrast() -> None:
    img = np.full((200, 200), 100.0, np.float32)
    out = speckle(img, Optics(speckle_contrast=0.3, speckle_px=1.0), np.random.default_rng(0))
    assert float(out.mean()) == pytest.approx(100.0, rel=0.02)
    assert float(out.std() / out.mean()) == pytest.approx(0.3, rel=0.1)
    assert speckle(img, Optics(speckle_contrast=0.3), None) is img  # noise-free frames


def test_field_blur_is_sharp_in_the_centre_and_soft_in_the_corners() -> None:
    img = np.zeros((101, 101), np.float32)
    img[50, 50] = img[8, 8] = 1.0
    out = field_blur(img, Optics(lens_blur_px=2.0))
    assert out[50, 50] == pytest.approx(1.0)  # r = 0: no extra blur
    assert out[8, 8] < 0.15 and out[:17, :17].sum() == pytest.approx(1.0, abs=0.02)


def test_bayer_mosaic_of_a_red_dot_demosaics_to_red_with_fringes() -> None:
    img = np.zeros((64, 64), np.float32)
    img[8:12, 8:12] = 200.0
    o = Optics(colour_response=(1.0, 0.0, 0.0), chromatic_px=1.0)
    e = mosaic(img, 0.0, o)
    assert e[1::2, 1::2].max() == 0 and e[0::2, 0::2].max() > 100  # RGGB: red at (0, 0)
    bgr = demosaic_and_encode(np.clip(e, 0, 255).astype(np.uint8), o)
    assert bgr.shape == (64, 64, 3) and bgr[..., 2].max() > 100 and bgr[..., 0].max() == 0
    # Lateral chromatic aberration: the red image is magnified away from the centre.
    yy, xx = np.mgrid[0:64, 0:64]
    blob = np.exp(-((xx - 10.0) ** 2 + (yy - 10.0) ** 2) / 8.0).astype(np.float32)
    m = mosaic(blob, 0.0, Optics(colour_response=(1.0, 1.0, 1.0), chromatic_px=1.0))

    def centroid(dy: int, dx: int) -> np.ndarray:
        w = m[dy::2, dx::2]
        return np.array([(w * xx[dy::2, dx::2]).sum(), (w * yy[dy::2, dx::2]).sum()]) / w.sum()

    # The blob lies 21.5 px left of and above the centre (31.5, 31.5); the corner is 44.5 px
    # away: red moves out by 21.5 / 44.5 px per axis, blue as far in.
    shift = centroid(0, 0) - centroid(1, 1)
    assert shift == pytest.approx([-2 * 21.5 / np.hypot(31.5, 31.5)] * 2, abs=0.05)


def test_blooming_spills_the_excess_along_the_column() -> None:
    e = np.zeros((41, 5), np.float32)
    e[20, 2] = 5000.0
    out = bloom(e, 1000.0, Optics(blooming=1.0))
    assert out[20, 2] == 1000.0 and out[18, 2] > 0 and out[20, 1] == 0
    assert float(out.sum()) == pytest.approx(5000.0, rel=1e-3)


def test_bad_optics_are_config_errors() -> None:
    with pytest.raises(SimError, match="colour"):
        get_preset("realistic").replace(chromatic_px=1.0)
    with pytest.raises(SimError, match="jpeg"):
        get_preset("realistic").replace(jpeg_quality=90, bit_depth=16)


@pytest.mark.parametrize("name", ["optics", "phone"])
def test_detection_on_real_optics_presets(name: str) -> None:
    p = get_preset(name).replace(width=480, height=320, dot_cols=9, dot_rows=6, fps=30.0)
    rig = SimRig(p, seed=2, n_frames=2)
    img = rig.render_frame(rig.frame_times_ns[1] * 1e-9)
    assert img.shape == (320, 480, 3) and img.dtype == np.uint8
    truth = [s for s in rig.frame_truth(1)["streaks"] if s["inside"]]
    fs = detect_frame(img)
    S = np.array([s["start"] for s in truth])
    E = np.array([s["end"] for s in truth])
    found = errs = 0
    err: list[float] = []
    for s, e in zip(S, E, strict=True):
        d1 = np.hypot(*(fs.end_a - s).T) + np.hypot(*(fs.end_b - e).T)
        d2 = np.hypot(*(fs.end_b - s).T) + np.hypot(*(fs.end_a - e).T)
        d = np.minimum(d1, d2)
        if d.size and d.min() < 8.0:
            found += 1
            err.append(float(d.min()) / 2)
        else:
            errs += 1
    assert found >= 0.9 * len(truth)
    assert np.median(err) < 1.5  # measured 1.08 (optics) px; see docs/detection.md
