"""The simulator and the core blur model agree; truth is consistent and sessions load back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.io import streaks
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.session import load_session
from rigs.sim.preset import get_preset
from rigs.sim.rig import SimRig
from rigs.sim.shake import default_shake_path
from rigs.sim.writer import write_session


def ideal_gyro(name: str, **changes):
    """A preset with a noise-free, bias-free 1 kHz gyro and synthetic motion (no data files)."""
    return get_preset(name).replace(
        gyro_noise_radps=0.0,
        gyro_bias_radps=0.0,
        gyro_scale_error=0.0,
        imu_rate_hz=1000.0,
        motion="synthetic",
        **changes,
    )


@pytest.fixture(scope="module")
def realistic_session(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "realistic"
    write_session(SimRig(ideal_gyro("realistic", synthetic_rms_radps=(0.8, 0.8, 0.4)), 11, 3), out)
    return out


def endpoint_errors(session_dir: Path) -> tuple[float, float]:
    s = load_session(session_dir)
    model = BlurModel(calibration_from_dict(s.truth["calibration"]), s.gyro())
    worst_px = worst_ns = 0.0
    for fr in s.truth["frames"]:
        st = fr["streaks"]
        ref = np.array([x["ref"] for x in st])
        start, end, t0, _t1 = model.streak_endpoints(
            ref, fr["t_ref_ns"] * 1e-9, fr["timestamp_ns"] * 1e-9, fr["exposure_ns"] * 1e-9
        )
        true_start = np.array([x["start"] for x in st])
        true_end = np.array([x["end"] for x in st])
        worst_px = max(
            worst_px,
            float(np.max(np.abs(start - true_start))),
            float(np.max(np.abs(end - true_end))),
        )
        worst_ns = max(worst_ns, float(np.max(np.abs(t0 * 1e9 - [x["t_start_ns"] for x in st]))))
    return worst_px, worst_ns


def test_core_model_reproduces_truth_realistic(realistic_session: Path) -> None:
    px, ns = endpoint_errors(realistic_session)
    assert px <= 0.02
    assert ns <= 1000.0  # the model stops after 4 fixed-point iterations: < 1 µs


def test_core_model_reproduces_truth_clean(tmp_path: Path) -> None:
    write_session(SimRig(ideal_gyro("clean"), 4, 2), tmp_path / "s")
    px, _ = endpoint_errors(tmp_path / "s")
    assert px <= 0.02


def test_wrong_calibration_does_not_reproduce_truth(realistic_session: Path) -> None:
    # The agreement above is not vacuous: a 10 ms offset error moves endpoints by pixels.
    s = load_session(realistic_session)
    cal = calibration_from_dict(s.truth["calibration"])
    bad = cal.with_(timeshift_cam_imu_s=cal.timeshift_cam_imu_s + 0.01)
    fr = s.truth["frames"][1]
    ref = np.array([x["ref"] for x in fr["streaks"]])
    start, _, _, _ = BlurModel(bad, s.gyro()).streak_endpoints(
        ref, fr["t_ref_ns"] * 1e-9, fr["timestamp_ns"] * 1e-9, fr["exposure_ns"] * 1e-9
    )
    err = np.abs(start - np.array([x["start"] for x in fr["streaks"]])).max()
    assert err > 1.0


def test_rolling_shutter_truth_times_match_rows(realistic_session: Path) -> None:
    s = load_session(realistic_session)
    ro = s.truth["calibration"]["cam0"]["readout_s"]
    H = s.truth["calibration"]["cam0"]["resolution"][1]
    assert ro > 0.01
    for fr in s.truth["frames"]:
        t_f, exp = fr["timestamp_ns"], fr["exposure_ns"]
        for x in fr["streaks"]:
            assert abs(x["t_start_ns"] - (t_f + 1e9 * ro * x["start"][1] / H)) <= 2
            assert abs(x["t_end_ns"] - (t_f + 1e9 * ro * x["end"][1] / H + exp)) <= 2


def test_session_loads_back_with_truth(realistic_session: Path) -> None:
    s = load_session(realistic_session, max_gyro_gap_s=0.01)
    truth = s.truth
    assert len(s.frames) == 3 and len(truth["frames"]) == 3
    assert s.frames.timestamp_ns.tolist() == [f["timestamp_ns"] for f in truth["frames"]]
    true_cal = calibration_from_dict(truth["calibration"])
    guess = s.initial_calibration()
    # session.yaml holds nominal guesses, not the truth.
    assert guess.camera.intrinsics != true_cal.camera.intrinsics
    assert guess.timeshift_cam_imu_s == 0.0 and true_cal.timeshift_cam_imu_s != 0.0
    assert not np.allclose(guess.R_cam_imu, true_cal.R_cam_imu, atol=1e-3)
    img = s.read_image(0)
    assert img.shape == (720, 1280) and img.dtype == np.uint8
    table = streaks.from_truth(truth)
    assert len(table) > 100
    for fr in truth["frames"]:
        for x in fr["streaks"]:
            cl = np.array(x["centerline"])
            assert 2 <= len(cl) <= 32
            np.testing.assert_allclose(cl[0], x["start"], atol=1e-3)
            np.testing.assert_allclose(cl[-1], x["end"], atol=1e-3)


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path) -> None:
    p = get_preset("realistic").replace(
        motion="synthetic", width=320, height=240, focal_px=250.0, dot_cols=6, dot_rows=4
    )
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        write_session(SimRig(p, seed, 2), tmp_path / name)
    files = sorted(
        f.relative_to(tmp_path / "a") for f in (tmp_path / "a").rglob("*") if f.is_file()
    )
    assert len(files) >= 6
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a" / "truth.yaml").read_bytes() != (
        tmp_path / "c" / "truth.yaml"
    ).read_bytes()


SHAKE = default_shake_path()


@pytest.mark.skipif(not SHAKE.is_file(), reason=f"shake traces absent: {SHAKE}")
@pytest.mark.parametrize("name", ["realistic", "hard"])
def test_core_model_reproduces_truth_on_real_shake(name: str) -> None:
    # Without rendering: the rig's truth against BlurModel on its ideal 1 kHz gyro.
    from blurtrack.geometry.gyro import GyroTrace

    p = get_preset(name).replace(
        gyro_noise_radps=0.0, gyro_bias_radps=0.0, gyro_scale_error=0.0, imu_rate_hz=1000.0
    )
    rig = SimRig(p, 21, 6)
    t_ns = rig.gyro_times_ns()
    model = BlurModel(rig.calibration, GyroTrace(t_ns * 1e-9, rig.sample_gyro(t_ns * 1e-9)))
    worst = 0.0
    for i in range(rig.n_frames):
        fr = rig.frame_truth(i)
        st = fr["streaks"]
        start, end, _, _ = model.streak_endpoints(
            np.array([x["ref"] for x in st]),
            fr["t_ref_ns"] * 1e-9,
            fr["timestamp_ns"] * 1e-9,
            fr["exposure_ns"] * 1e-9,
        )
        worst = max(
            worst,
            float(np.abs(start - [x["start"] for x in st]).max()),
            float(np.abs(end - [x["end"] for x in st]).max()),
        )
    assert worst <= 0.02


def test_core_model_reproduces_truth_with_lens_distortion(tmp_path: Path) -> None:
    p = ideal_gyro(
        "realistic",
        distortion_coeffs=(-0.12, 0.03, 0.001, -0.0015),
        width=640,
        height=360,
        focal_px=500.0,
    )
    write_session(SimRig(p, 8, 2), tmp_path / "s")
    s = load_session(tmp_path / "s")
    assert s.truth["calibration"]["cam0"]["distortion_model"] == "radtan"
    assert s.meta.camera.distortion_model == "none"  # the rig's guess
    px, _ = endpoint_errors(tmp_path / "s")
    assert px <= 0.02
