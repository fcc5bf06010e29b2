"""The natural-scene report (blurtrack.report.natural) on a simulated session with known truth:
the axis-search table is the calibration's, registered rotations match the true motion, and
the calibration's track errors and rotation agreement beat a wrong initial guess."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.geometry.rotation import so3_log
from blurtrack.io.yamlio import read_yaml, write_yaml
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session


@pytest.fixture(scope="module")
def reported(tmp_path_factory, shared_data) -> tuple[NaturalRig, Path, dict, dict]:
    root = tmp_path_factory.mktemp("natrep")
    rig = NaturalRig(get_preset("realistic").replace(width=320, height=180, focal_px=250.0), 3, 24)
    s = root / "s"
    write_session(rig, s)
    meta = read_yaml(s / "session.yaml", "session.yaml")
    meta["imu"]["T_cam_imu"] = np.eye(4).tolist()  # a wrong initial guess: "before"
    write_yaml(s / "session.yaml", meta)
    calib = root / "c" / "calib.yaml"
    assert main(["calibrate", str(s), "--out", str(calib)]) == 0
    assert main(["report", str(s), "--calib", str(calib), "--out", str(root / "r")]) == 0
    fit = json.loads(calib.with_name("calib.summary.json").read_text())
    rep = json.loads((root / "r" / "summary.json").read_text())
    return rig, root / "r", fit, rep


def test_axis_table_is_the_calibrations(reported) -> None:
    _, out, fit, rep = reported
    ax = rep["natural"]["axes"]
    assert ax["margin"] == pytest.approx(fit["axes"]["margin"])
    assert ax["winner"] == fit["axes"]["winner"] and len(ax["candidates"]) == 24
    text = (out / "report.html").read_text()
    assert f"margin over the runner-up <b>{fit['axes']['margin']:.2f}</b>" in text
    table = text.split("<h2>Axis search</h2>")[1].split("</table>")[0]
    assert len(re.findall("<tr>", table)) == 25  # header + 24 candidates
    assert "Registered and gyro rotations per frame pair" in text


def test_track_errors_and_rotation_agreement(reported) -> None:
    _, out, _, rep = reported
    nat = rep["natural"]
    te, ag = nat["track_errors"], nat["agreement"]
    assert te["after"]["median_px"] < 0.3
    assert te["before"]["median_px"] > 5 * te["after"]["median_px"]  # the wrong axes
    assert ag["after"]["median_deg"] < 0.1 and ag["before"]["median_deg"] > 1.0
    df = pd.read_csv(out / "track_errors.csv")
    assert len(df) == 2 * nat["n_tracks"]
    after = df[df["calibration"] == "after"]["error_px"].to_numpy()
    assert np.median(after) == pytest.approx(te["after"]["median_px"], rel=1e-4)


def test_registered_rotations_match_the_true_motion(reported) -> None:
    """The image side against the same registration of the simulator's true point motion."""
    from blurtrack.report.natural import register_rotation

    rig, out, _, _ = reported
    df = pd.read_csv(out / "pair_rotations.csv")
    df = df[df["calibration"] == "after"]
    tr = pd.read_csv(out / "track_errors.csv")
    tr = tr[tr["calibration"] == "after"]
    assert len(df) >= 20
    cam = rig.camera
    H, r, e = cam.height, cam.readout_s, rig.preset.exposure_s
    t = rig.frame_times_ns * 1e-9
    errs, moved = [], []
    for _, row in df.iterrows():
        f = int(row["frame"])
        sel = tr[tr["frame"] == f]
        pa = sel[["x", "y"]].to_numpy(float)
        ta = t[f] + r * pa[:, 1] / H + e / 2
        tb = t[f + 1] + r * sel["y_next"].to_numpy(float) / H + e / 2
        Ra, Rb = rig.motion.orientation(ta), rig.motion.orientation(tb)
        ray = cam.unproject(pa)
        w = np.einsum("nij,nj->ni", Ra, ray)  # world directions
        true_b = np.einsum("nji,nj->ni", Rb, w)  # seen from the later rows
        unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
        truth = np.degrees(so3_log(register_rotation(unit(ray), unit(true_b)).T))
        img = row[["image_deg_x", "image_deg_y", "image_deg_z"]].to_numpy(float)
        errs.append(np.linalg.norm(img - truth))
        moved.append(np.linalg.norm(truth))
    assert np.median(errs) < 0.04  # 0.17 px at fx 250: tracking noise
    assert np.median(moved) > 20 * np.median(errs)  # negative control: the pairs did rotate
