"""Presets (validation, YAML round trip) and the GyroDeblurNet shake-trace reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigs.sim.errors import SimError
from rigs.sim.motion import shake_omega
from rigs.sim.preset import PRESETS, SimPreset, get_preset
from rigs.sim.shake import ShakeTrace, default_shake_path, read_shake_trace

SHAKE = default_shake_path()
needs_shake = pytest.mark.skipif(not SHAKE.is_file(), reason=f"shake traces absent: {SHAKE}")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_round_trip_through_yaml(name: str, tmp_path: Path) -> None:
    p = get_preset(name)
    p.to_yaml(tmp_path / "p.yaml")
    assert SimPreset.from_yaml(tmp_path / "p.yaml") == p


def test_preset_contents_follow_the_brief() -> None:
    clean, real, hard = (get_preset(n) for n in ("clean", "realistic", "hard"))
    assert clean.readout_s == 0 and clean.gyro_noise_radps == 0 and clean.shot_noise is False
    assert real.exposure_s == 0.02 and real.readout_s > 0 and real.gyro_bias_radps > 0
    assert real.timeshift_s == (0.005, 0.030) and real.misalignment_deg == (1.0, 2.0)
    assert 0.003 <= real.gyro_noise_radps <= 0.01 and real.imu_rate_hz == 200.0
    assert hard.motion_scale[0] > 1.5 and hard.dot_fill > 1.0
    assert (clean.width, clean.height, clean.dot_cols, clean.dot_rows) == (1280, 720, 15, 11)


def test_preset_file_with_base_and_overrides(tmp_path: Path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text("base: realistic\nname: mine\nexposure_s: 0.015\nmisalignment_deg: [0, 0]\n")
    p = SimPreset.from_yaml(f)
    assert p.name == "mine" and p.exposure_s == 0.015 and p.readout_s == 0.025
    assert p.misalignment_deg == (0.0, 0.0)


@pytest.mark.parametrize(
    "text, message",
    [
        ("exposure_s: 0.5\n", "exposure_s"),
        ("bogus_key: 1\n", "unknown preset keys"),
        ("width: 12.5\n", "integer"),
        ("shot_noise: 1\n", "true or false"),
        ("motion: wobbly\n", "motion"),
        ("timeshift_s: [0.03, 0.01]\n", "timeshift_s"),
        ("bit_depth: 12\n", "bit_depth"),
        ("dot_flux_eps: .nan\n", "finite"),
        ("- 1\n- 2\n", "mapping"),
        ("a: [unclosed\n", "not valid YAML"),
        ("base: nothing\n", "unknown preset"),
    ],
)
def test_bad_preset_files_fail_with_one_line(tmp_path: Path, text: str, message: str) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(SimError, match=message) as exc:
        SimPreset.from_yaml(f)
    assert "\n" not in str(exc.value)


@needs_shake
def test_reads_the_real_shake_traces() -> None:
    tr = read_shake_trace(SHAKE)
    assert tr.omega_radps.shape == (39116, 3)
    assert 205 < tr.rate_hz < 215
    assert 185 < tr.duration_s < 188
    gaps = tr.gaps()
    assert len(gaps) == 1 and 0.020 < gaps[0][1] - gaps[0][0] < 0.030
    assert 0.5 < float(np.median(np.linalg.norm(tr.omega_radps, axis=1))) < 0.9


@needs_shake
def test_resampling_bridges_the_dropout_smoothly() -> None:
    tr = read_shake_trace(SHAKE)
    g0, g1 = tr.gaps()[0]
    t, w = tr.resampled(g0 - 0.5, 1.0, rate_hz=1000.0, band_hz=(0.0, 25.0))
    assert np.all(np.isfinite(w)) and np.all(np.diff(t) > 0)
    # No jump at the bridged gap: sample-to-sample changes there are like everywhere else.
    step = np.abs(np.diff(w, axis=0)).max(axis=1)
    inside = (t[1:] > 0.5 - 0.01) & (t[1:] < 0.5 + (g1 - g0) + 0.01)
    assert step[inside].max() < 3 * np.percentile(step, 99)
    # Band-limited to hand shake: agrees with the raw samples to a fraction of their spread.
    raw = (tr.t_s > g0 - 0.4) & (tr.t_s < g0 - 0.1)
    interp = np.stack([np.interp(tr.t_s[raw] - (g0 - 0.5), t, w[:, k]) for k in range(3)], 1)
    assert np.sqrt(np.mean((interp - tr.omega_radps[raw]) ** 2)) < 0.3 * tr.omega_radps.std()


@needs_shake
def test_shake_motion_is_seeded_and_scaled() -> None:
    tr = read_shake_trace(SHAKE)
    a = shake_omega(tr, np.random.default_rng(3), 2.0, (2.0, 2.0), (1.0, 15.0))
    b = shake_omega(tr, np.random.default_rng(3), 2.0, (2.0, 2.0), (1.0, 15.0))
    c = shake_omega(tr, np.random.default_rng(4), 2.0, (2.0, 2.0), (1.0, 15.0))
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2]["start_s"] != c[2]["start_s"] and a[2]["scale"] == 2.0
    assert a[0][0] == pytest.approx(0.0, abs=2e-3) and a[0][-1] >= 2.0 - 1e-9


@pytest.mark.parametrize(
    "text, message",
    [
        ("1\t0.1\t0.2\n2\t0.1\n", "has 3 fields, expected 4"),
        ("1\t0.1\t0.2\tx\n" * 5, "not numeric"),
        ("".join(f"{k}\t0\t0\t0\n" for k in (1, 2, 3, 3, 4)), "not increasing"),
        ("1\t0\t0\tnan\n2\t0\t0\t0\n3\t0\t0\t0\n4\t0\t0\t0\n", "NaN"),
        ("1\t0\t0\t0\n", "fewer than 2 samples"),
    ],
)
def test_bad_shake_files(tmp_path: Path, text: str, message: str) -> None:
    f = tmp_path / "g.txt"
    f.write_text(text)
    with pytest.raises(SimError, match=message):
        read_shake_trace(f)


def test_missing_and_binary_shake_files(tmp_path: Path) -> None:
    with pytest.raises(SimError, match="not found"):
        read_shake_trace(tmp_path / "nope.txt")
    f = tmp_path / "b.txt"
    f.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SimError, match="UTF-8"):
        read_shake_trace(f)


def test_short_trace_is_refused_for_long_motion() -> None:
    t = np.arange(0, 3.0, 0.005)
    tr = ShakeTrace(t, np.zeros((t.size, 3)), "tiny")
    with pytest.raises(SimError, match="too short"):
        shake_omega(tr, np.random.default_rng(0), 5.0, (1.0, 1.0), (1.0, 15.0))
