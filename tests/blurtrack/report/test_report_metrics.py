"""Endpoint-error metrics and the HTML page of blurtrack.report (no calib, no CasADi)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io import streaks as streak_table
from blurtrack.report.html import render
from blurtrack.report.metrics import ReportError, endpoint_errors, per_frame, stats


def _scene(seed: int = 0, amp: float = 2.0):
    rng = np.random.default_rng(seed)
    cam = Camera((640, 480), (500.0, 502.0, 320.0, 240.0), readout_s=0.02)
    calib = Calibration(
        cam,
        R_cam_imu=np.eye(3),
        timeshift_cam_imu_s=0.004,
        gyro_bias_radps=np.array([0.01, 0.0, -0.01]),
    )
    t = np.arange(9.5, 11.0, 0.002)
    w = np.stack(
        [amp * np.sin(2 * np.pi * f * t + p) for f, p in ((3.0, 0.1), (4.0, 1.0), (2.5, 2.0))],
        axis=1,
    )
    gyro = GyroTrace(t, w)
    model = BlurModel(calib, gyro)
    rows, frames = [], []
    for i in range(4):
        ft, exp = 10.0 + 0.1 * i, 0.03
        px = np.stack([rng.uniform(60, 580, 30), rng.uniform(60, 420, 30)], axis=1)
        s, e, _, _ = model.streak_endpoints(px, model.default_reference_time(ft, exp), ft, exp)
        frames.append({"timestamp_ns": round(ft * 1e9), "exposure_ns": round(exp * 1e9)})
        for k in range(30):
            rows.append(
                {
                    "frame": i,
                    "timestamp_ns": round(ft * 1e9),
                    "streak_id": k,
                    "start_x": s[k, 0],
                    "start_y": s[k, 1],
                    "end_x": e[k, 0],
                    "end_y": e[k, 1],
                    "length_px": float(np.linalg.norm(e[k] - s[k])),
                    "centerline": [],
                    "profile": [],
                    "orientation_confidence": 1.0,
                    "orientation_source": "truth",
                    "clipped": False,
                    "saturated": False,
                    "merged": False,
                    "faint": False,
                }
            )
    table = streak_table.validate(pd.DataFrame(rows))
    return calib, gyro, table, pd.DataFrame(frames)


def test_zero_error_at_the_true_calibration() -> None:
    calib, gyro, table, frames = _scene()
    df = endpoint_errors(gyro, table, frames, calib)
    assert df["covered"].all()
    assert float(np.median(np.hypot(table.end_x - table.start_x, table.end_y - table.start_y))) > 5
    assert df["error_px"].max() < 3e-3  # sub-step counts differ from the generator's
    assert np.all(df["omega_radps"] > 0)


def test_wrong_shift_and_models_rank_as_expected() -> None:
    calib, gyro, table, frames = _scene()
    off = endpoint_errors(gyro, table, frames, calib.with_(timeshift_cam_imu_s=0.009))
    assert off["error_px"].mean() > 0.3
    glob = endpoint_errors(gyro, table, frames, calib, rolling=False)
    small = endpoint_errors(gyro, table, frames, calib, rotation_model="small_angle")
    exact = endpoint_errors(gyro, table, frames, calib)
    assert glob["error_px"].mean() > 0.05  # ignoring the 20 ms readout is visible
    # The paper's per-axis small angles are visibly worse at 2 rad/s on three axes.
    assert small["error_px"].mean() > 0.01 > exact["error_px"].mean()


def test_uncovered_frames_are_marked_not_counted() -> None:
    calib, gyro, table, frames = _scene()
    short = GyroTrace(gyro.t_s[gyro.t_s < 10.15], gyro.omega_radps[gyro.t_s < 10.15])
    df = endpoint_errors(short, table, frames, calib)
    assert not df["covered"].all() and df["covered"].any()
    assert np.all(np.isnan(df.loc[~df["covered"], "error_px"]))
    s = stats(df["error_px"].to_numpy())
    assert s["n"] == int(df["covered"].sum())
    pf = per_frame({"x": df})
    assert len(pf) == 4 and pf["n"].min() == 0


def test_bad_input() -> None:
    calib, gyro, table, frames = _scene()
    with pytest.raises(ReportError, match="empty"):
        endpoint_errors(gyro, table.iloc[:0], frames, calib)
    bad = table.copy()
    bad.loc[0, "frame"] = 99
    with pytest.raises(ReportError, match="frames"):
        endpoint_errors(gyro, bad, frames, calib)


def test_stats_known_values() -> None:
    s = stats(np.array([1.0, 2.0, 3.0, np.nan]))
    assert s == {
        "n": 3,
        "mean_px": 2.0,
        "median_px": 2.0,
        "p95_px": pytest.approx(2.9),
        "rms_px": pytest.approx(np.sqrt(14 / 3)),
    }


def test_html_is_self_contained_and_escaped() -> None:
    summary = {
        "n_streaks": 3,
        "n_frames": 1,
        "warnings": ["<script>x</script>"],
        "overall": {"before": stats(np.ones(3)), "after": stats(np.zeros(3))},
        "motion_models": {"exact_rolling": stats(np.zeros(3))},
        "motion_model_labels": {"exact_rolling": "exact + RS"},
        "fit": {},
    }
    fs = pd.DataFrame(
        [
            {"variant": "before", "frame": 0, "mean_px": 1.0},
            {"variant": "after", "frame": 0, "mean_px": 0.0},
        ]
    )
    page = render(summary, [("fig", b"\x89PNG")], fs)
    assert "<script>" not in page and "&lt;script&gt;" in page
    assert "data:image/png;base64,iVBORw==" in page
    assert "exact + RS" in page


def test_blur_model_applies_a_calibrated_gyro_scale() -> None:
    from blurtrack.geometry.blur_model import BlurModel

    calib, gyro, _, _ = _scene()
    M = np.array([[1.02, 0.004, 0.0], [0.004, 0.99, 0.0], [0.0, 0.0, 1.0]])
    meas = GyroTrace(
        gyro.t_s, (gyro.omega_radps - calib.gyro_bias_radps) @ M.T + calib.gyro_bias_radps
    )
    t = np.linspace(gyro.t_s[5], gyro.t_s[-5], 50) - calib.timeshift_cam_imu_s
    want = np.stack(BlurModel(calib, gyro).omega_cam_at(t), axis=1)
    got = np.stack(BlurModel(calib.with_(gyro_scale_matrix=M), meas).omega_cam_at(t), axis=1)
    np.testing.assert_allclose(got, want, atol=1e-12)
    naive = np.stack(BlurModel(calib, meas).omega_cam_at(t), axis=1)
    assert np.abs(naive - want).max() > 1e-3
