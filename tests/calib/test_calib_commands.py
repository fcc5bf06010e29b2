"""`blurtrack calibrate` and `blurtrack report` end to end on a small synthetic session."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.geometry.calibration import Calibration
from blurtrack.io import streaks as streak_table
from blurtrack.io.calibration import calibration_to_dict, read_calibration
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, load_session
from blurtrack.testing.turned import turn_session
from calib.cli import refuse_bottom_first
from calib.testing import make_problem


def _write_session(folder: Path, seed: int = 21, tracked: bool = False) -> tuple[Path, Calibration]:
    p = make_problem(
        seed=seed,
        n_frames=10,
        dots_per_frame=30,
        endpoint_noise_px=0.05,
        shift_error_s=0.02,
        focal_error=0.04,
        tracked=tracked,
    )
    s = p.streaks
    T = np.eye(4)
    T[:3, :3] = p.initial.R_cam_imu
    meta = SessionMeta(
        camera=p.initial.camera, imu=ImuConfig(200.0, T, p.initial.timeshift_cam_imu_s)
    )
    frame_t_ns = np.round((np.unique(s.frame_t_s) + s.t0_s) * 1e9).astype(np.int64)
    with SessionWriter(folder, meta) as w:
        for ts in frame_t_ns:
            w.add_frame(int(ts), np.zeros((720, 1280), np.uint8), 20_000_000)
        w.add_imu(np.round(p.gyro.t_s * 1e9).astype(np.int64), p.gyro.omega_radps)
        frames = []
        for i, ts in enumerate(frame_t_ns):
            sel = s.frame == i
            frames.append(
                {
                    "index": i,
                    "timestamp_ns": int(ts),
                    "exposure_ns": 20_000_000,
                    "streaks": [
                        {
                            "dot": int(d),
                            "start": a.tolist(),
                            "end": b.tolist(),
                            "centerline": [a.tolist(), b.tolist()],
                            "inside": True,
                            **({"mid": m.tolist()} if tracked else {}),
                        }
                        for d, a, b, m in zip(
                            s.streak_id[sel],
                            s.start[sel],
                            s.end[sel],
                            (s.mid if tracked else s.start)[sel],
                            strict=True,
                        )
                    ],
                }
            )
        w.write_truth(
            {
                "calibration": calibration_to_dict(p.truth),
                "simulator": {"preset": "test"},
                "frames": frames,
            }
        )
    from blurtrack.io.session import load_session

    table = streak_table.from_truth(load_session(folder).truth)
    streak_table.write(table, folder / "streaks.parquet")
    return folder, p.truth


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Calibration]:
    return _write_session(tmp_path_factory.mktemp("calib_cli") / "sess")


def test_calibrate_and_report(session_dir, tmp_path: Path, capsys) -> None:
    folder, truth = session_dir
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", str(folder), "--out", str(out), "--holdout", "0.2"]) == 0
    text = capsys.readouterr().out
    assert "truth" in text and "timeshift_s" in text
    cal = read_calibration(out)
    assert abs(cal.timeshift_cam_imu_s - truth.timeshift_cam_imu_s) < 2e-4
    assert "timeshift_cam_imu" in cal.sigma and len(cal.sigma["intrinsics"]) == 4
    summ = json.loads((tmp_path / "calib.summary.json").read_text())
    assert summ["status"] in ("ok", "warning")
    assert abs(summ["error_vs_truth"]["fx"]) < 2.0
    assert (tmp_path / "calib.openvins.yaml").read_text().startswith("%YAML:1.0")
    assert (tmp_path / "calib.camera_info.yaml").is_file()

    rep = tmp_path / "report"
    assert (
        main(
            [
                "report",
                str(folder),
                "--calib",
                str(out),
                "--out",
                str(rep),
                "--from-truth",
                "--overlays",
                "1",
            ]
        )
        == 0
    )
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["overall"]["after"]["mean_px"] < 0.3
    assert summary["overall"]["before"]["mean_px"] > summary["overall"]["after"]["mean_px"]
    mm = summary["motion_models"]
    assert mm["exact_rolling"]["mean_px"] < mm["exact_global"]["mean_px"]
    html = (rep / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 7 and "src='http" not in html
    errs = pd.read_csv(rep / "streak_errors.csv")
    assert set(errs["variant"]) == {
        "before",
        "after",
        "paper_small_angle",
        "exact_global",
        "small_angle_rolling",
        "exact_rolling",
    }
    frames = pd.read_csv(rep / "frame_errors.csv")
    assert frames["frame"].nunique() == 10


def test_bad_fit_list_and_missing_streaks(session_dir, tmp_path: Path, capsys) -> None:
    folder, _ = session_dir
    assert (
        main(["calibrate", str(folder), "--out", str(tmp_path / "c.yaml"), "--fit", "fx,zoom"]) == 2
    )
    assert "zoom" in capsys.readouterr().err
    assert (
        main(
            [
                "calibrate",
                str(folder),
                "--out",
                str(tmp_path / "c.yaml"),
                "--streaks",
                str(tmp_path / "nope.parquet"),
            ]
        )
        == 2
    )
    assert "not found" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_report_rejects_garbled_calibration(session_dir, tmp_path: Path, capsys) -> None:
    folder, _ = session_dir
    bad = tmp_path / "bad.yaml"
    bad.write_text("cam0: [1, 2\n")
    assert main(["report", str(folder), "--calib", str(bad), "--out", str(tmp_path / "r")]) == 2
    assert "not valid YAML" in capsys.readouterr().err


def test_calibrate_with_centre_lines(session_dir, tmp_path: Path, capsys) -> None:
    folder, truth = session_dir
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", str(folder), "--out", str(out), "--from-truth", "--centreline"]) == 0
    capsys.readouterr()
    cal = read_calibration(out)
    summ = json.loads((tmp_path / "calib.summary.json").read_text())
    # Centre lines weigh this small session's shift to z ~ 3 (200-220 µs, sigma 74 µs after
    # the refit on every frame; the training fit 198 µs, as before the refit existed).
    err = abs(cal.timeshift_cam_imu_s - truth.timeshift_cam_imu_s)
    assert err < min(4 * summ["sigma"]["timeshift_s"], 5e-4)
    assert summ["status"] in ("ok", "warning")
    assert summ["options"]["centreline"] is True
    assert summ["refitted_on_all_frames"] and summ["holdout_fit_values"]


def test_calibrate_fits_tracks_where_dots_persist(tmp_path: Path, capsys) -> None:
    folder, _ = _write_session(tmp_path / "tracked", seed=22, tracked=True)
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", str(folder), "--out", str(out)]) == 0
    assert "fitted tracks:" in capsys.readouterr().out
    summ = json.loads((tmp_path / "calib.summary.json").read_text())
    assert summ["residuals"] == "tracks" and summ["n_tracks"] > 150
    assert summ["tracks_inliers"]["mean_px"] < 0.2
    assert abs(summ["error_vs_truth"]["fx"]) < 2.0
    rep = tmp_path / "report"
    assert (
        main(["report", str(folder), "--calib", str(out), "--out", str(rep), "--overlays", "0"])
        == 0
    )
    assert "fitted residuals: <b>tracks</b>" in (rep / "report.html").read_text()


def test_tracks_refused_without_midpoints(session_dir, tmp_path: Path, capsys) -> None:
    folder, _ = session_dir  # its truth (and so its table) has no midpoints
    assert (
        main(
            [
                "calibrate",
                str(folder),
                "--out",
                str(tmp_path / "c.yaml"),
                "--from-truth",
                "--residuals",
                "tracks",
            ]
        )
        == 2
    )
    assert "midpoints" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "c.yaml"), "--from-truth"]) == 0
    assert "fitted endpoints" in capsys.readouterr().out
    summ = json.loads((tmp_path / "c.summary.json").read_text())
    assert summ["residuals"] == "endpoints"
    assert any("no time midpoints" in w for w in summ["warnings"])


def test_truth_rotation_is_the_one_the_gyro_data_define() -> None:
    """``truth_values``: the gyro scale matrix's rotation factor belongs to the mounting
    rotation (polar decomposition), its symmetric part to the scale entries."""
    from types import SimpleNamespace

    from blurtrack.geometry.camera import Camera
    from blurtrack.geometry.rotation import so3_exp, so3_log
    from calib.truth import truth_values

    R = so3_exp(np.array([0.02, -0.01, 0.03]))
    initial = Calibration(Camera((64, 48), (50.0, 50.0, 32.0, 24.0)))
    truth = Calibration(Camera((64, 48), (50.0, 50.0, 32.0, 24.0)), R_cam_imu=R)
    Q = so3_exp(np.array([0.0, 0.004, -0.003]))
    P = np.eye(3) + np.diag([0.002, -0.001, 0.003])
    sim = {"gyro": {"scale_matrix": (P @ Q).tolist()}}
    tv = truth_values(
        SimpleNamespace(truth={"calibration": calibration_to_dict(truth), "simulator": sim}),
        initial,
    )
    rot = np.array([tv["rot_x"], tv["rot_y"], tv["rot_z"]])
    assert np.allclose(rot, so3_log(R @ Q.T), atol=1e-12)
    # the symmetric part of M - I: P - I to first order (second-order terms ~1e-5)
    assert abs(tv["scale_xx"] - 0.002) < 1e-4 and abs(tv["scale_zz"] - 0.003) < 1e-4
    # negative control: without the scale matrix the truth is the stated rotation
    plain = truth_values(
        SimpleNamespace(truth={"calibration": calibration_to_dict(truth)}), initial
    )
    assert np.allclose([plain["rot_x"], plain["rot_y"], plain["rot_z"]], so3_log(R), atol=1e-12)
    assert np.degrees(np.linalg.norm(rot - so3_log(R))) > 0.2


def test_calibrate_refuses_frames_read_bottom_first(tmp_path: Path) -> None:
    # Detection turns such frames for itself; calibration's model reads the top row first.
    upright = tmp_path / "upright"
    assert main(["simulate", str(upright), "--preset", "realistic", "--frames", "4"]) == 0
    turned = tmp_path / "turned"
    turn_session(upright, turned)
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", str(turned), "--out", str(out)]) == 2
    assert not out.exists()
    summary = json.loads((turned / "derived" / "streaks.summary.json").read_text())
    assert summary["gyro_readout_order"]["status"] == "bottom_first"
    # Negative control: the upright session's detection summary lets the fit go on.
    assert main(["detect", str(upright)]) == 0
    args = argparse.Namespace(from_truth=False, streaks=None, session=str(upright))
    refuse_bottom_first(args, load_session(upright))
