"""Importers on the real recordings, and their failure modes on damaged copies."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.errors import ImportFormatError
from blurtrack.io.importers import fit_radtan4, import_deepgyro, import_marslogger
from blurtrack.io.session import load_session
from blurtrack.io.shake import read_shake_trace


def test_deepgyro_import_and_overlays(shared_data: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "dg"
    assert (
        main(
            [
                "import",
                "deepgyro",
                str(shared_data / "real" / "deepgyro-shield"),
                str(out),
                "--overlays",
                "7",
            ]
        )
        == 0
    )
    s = load_session(out)
    assert len(s.frames) == 7 and s.omega_radps.shape == (23, 3)
    assert s.meta.camera.resolution == (1920, 1080)
    assert s.meta.camera.intrinsics[0] == pytest.approx(1558.6899)
    R = s.meta.imu.T_cam_imu[:3, :3]
    assert np.linalg.det(R) == pytest.approx(1.0)
    # ω_cam x/y are the IMU's y/x, as the data README says; only a guess, marked as such.
    np.testing.assert_allclose(R[:2, :2], [[0, 1], [1, 0]])
    assert s.meta.imu.axes_known is False
    assert "UNKNOWN" in s.meta.extra["import"]["assumptions"]["R_cam_imu"]
    text = capsys.readouterr().out
    assert "axes unknown" in text and "labelled" in text
    assert "frame 0 not drawn: gyro covers" in text  # the burst starts before the gyro log
    overlays = sorted((out / "overlays").glob("overlay_*.png"))
    assert 3 <= len(overlays) < 7


def test_marslogger_import(shared_data: Path, tmp_path: Path) -> None:
    summary = import_marslogger(shared_data / "real" / "marslogger-phone", tmp_path / "m")
    s = load_session(tmp_path / "m")
    assert s.meta.camera.resolution == (1080, 1920)
    assert s.meta.camera.distortion_model == "radtan"
    fx, _fy, cx, cy = s.meta.camera.intrinsics
    assert 1400 < fx < 1520 and abs(cx - 539.5) < 20 and abs(cy - 959.5) < 30
    assert s.meta.camera.readout_s == pytest.approx(0.005628402)
    assert s.accel_mps2 is not None and s.accel_mps2.shape == s.omega_radps.shape
    assert summary["frames"] == 10 and summary["frames_covered_by_gyro"] < 10
    assert s.meta.imu.axes_known is False


def test_radtan_refit_is_exact_for_a_four_coefficient_model() -> None:
    (k1, k2, _, _), err = fit_radtan4(np.array([0.1, -0.05, 0.0, 0.0, 0.0]), 0.8)
    assert (k1, k2) == pytest.approx((0.1, -0.05)) and err < 1e-12


def test_damaged_deepgyro_copies_fail_with_one_line(shared_data: Path, tmp_path: Path) -> None:
    src = tmp_path / "src"
    shutil.copytree(shared_data / "real" / "deepgyro-shield", src)
    (src / "imu" / "imu.txt").write_text("4 100 1.0 2.0\n")
    with pytest.raises(ImportFormatError, match="expected 5 fields"):
        import_deepgyro(src, tmp_path / "a")
    shutil.copy(shared_data / "real" / "deepgyro-shield" / "imu" / "imu.txt", src / "imu")
    (src / "images" / "0003.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(ImportFormatError, match="does not decode"):
        import_deepgyro(src, tmp_path / "b")
    assert main(["import", "deepgyro", str(src), str(tmp_path / "c")]) == 2


def test_shake_trace_reader(shared_data: Path, tmp_path: Path) -> None:
    tr = read_shake_trace(shared_data / "real" / "gyrodeblurnet-shake" / "gyro_train.txt")
    assert tr.t_s[0] == 0.0 and 180 < tr.t_s[-1] < 190
    assert 200 < tr.rate_hz < 220
    assert 0.5 < np.median(np.linalg.norm(tr.omega_radps, axis=1)) < 0.8
    gap = int(np.argmax(np.diff(tr.t_s)))
    assert not tr.covers(tr.t_s[gap] - 0.001, tr.t_s[gap + 1] + 0.001)  # the 26 ms dropout
    bad = tmp_path / "bad.txt"
    bad.write_text("1\t0.1\t0.2\t0.3\n2\t0.1\tx\t0.3\n")
    with pytest.raises(ImportFormatError, match="line 2 is not numeric"):
        read_shake_trace(bad)
