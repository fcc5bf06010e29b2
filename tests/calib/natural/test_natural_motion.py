"""Camera translation as a nuisance (calib.natural.motion): the epipolar residual is exact for
a translating camera, the data choose the model, and on a simulated driving session the time
offset is recovered with it and the calibration is wrong without it (negative control)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.geometry.rotation import so3_exp
from calib.natural.motion import AUTO_RATIO, epipolar_residual, epipoles, prefers_translation
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

K = np.array([[300.0, 0, 160], [0, 310.0, 90], [0, 0, 1]])


def _project(X: np.ndarray) -> np.ndarray:
    x = X @ K.T
    return x[:, :2] / x[:, 2:3]


def _pair(rng: np.random.Generator, t: np.ndarray, n: int = 60):
    p = rng.uniform([0, 0], [320, 180], (n, 2))
    depth = rng.uniform(3, 12, n)
    X = np.column_stack([p, np.ones(n)]) @ np.linalg.inv(K).T * depth[:, None]
    R = so3_exp(rng.normal(0, 0.02, 3))
    pred = _project(X @ R.T)  # carried by the rotation alone
    obs = _project(X @ R.T + t)  # what a translating camera sees
    return pred, obs


@pytest.mark.parametrize("t", [(0.0, 0.0, 0.3), (0.2, -0.1, 0.05), (0.3, 0.1, 0.0)])
def test_epipolar_residual_vanishes_for_a_translating_camera(t) -> None:
    rng = np.random.default_rng(3)
    t = np.array(t)
    pred, obs = _pair(rng, t)
    c, f = np.array([160.0, 90.0]), 300.0
    E = epipoles(pred, obs, np.zeros(len(obs), np.int64), c, f)
    r = epipolar_residual(pred, obs, np.repeat(E, len(obs), 0), c, f)
    assert np.max(np.abs(r)) < 1e-6
    # the recovered epipole is K t (conditioned coordinates), up to scale and sign
    e_true = np.array([K[0, 0] * t[0] / f, K[1, 1] * t[1] / f, t[2]])  # c = (cx, cy)
    assert abs(abs(E[0] @ e_true) / np.linalg.norm(e_true) - 1) < 1e-6
    # negative controls: the parallax is real, and a wrong epipole leaves residuals
    assert np.median(np.linalg.norm(obs - pred, axis=1)) > 1
    wrong = np.repeat(np.array([[0.5, 0.5, 1.0]]), len(obs), 0)
    assert np.median(np.abs(epipolar_residual(pred, obs, wrong, c, f))) > 0.1


def test_auto_rule() -> None:
    assert not prefers_translation(2.0, 1.0)
    assert prefers_translation(AUTO_RATIO * 1.1, 1.0)


def _summary(out: Path) -> dict:
    return json.loads(out.with_name("calib.summary.json").read_text())


@pytest.fixture(scope="module")
def driving(tmp_path_factory, shared_data) -> Path:
    """A car at 3 m/s (±30 %) towards a photographed plane 8 m away, 1 s of 320x180 video."""
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    s = tmp_path_factory.mktemp("drive") / "s"
    write_session(NaturalRig(preset, 5, 30, depth_m=8.0, speed_mps=3.0, speed_wobble=0.3), s)
    return s


def test_driving_session_offset_with_the_nuisance_and_not_without(driving, tmp_path) -> None:
    out = tmp_path / "auto" / "calib.yaml"
    assert main(["calibrate", str(driving), "--out", str(out)]) == 0
    d = _summary(out)
    assert d["translation"]["mode"] == "travel" and d["translation"]["chosen_by"] == "data"
    assert d["translation"]["ratio"] > AUTO_RATIO
    # held-out frame pairs predicted by the travel fit (calib.natural.travel)
    assert d["holdout_all"]["n"] > 0 and d["refitted_on_all_frames"]
    err, tru = d["error_vs_truth"], d["truth"]
    assert abs(err["timeshift_s"]) < 1e-3
    assert abs(err["fx"]) / tru["fx"] < 0.02 and abs(err["fy"]) / tru["fy"] < 0.02
    rot = math.degrees(math.sqrt(sum(err[k] ** 2 for k in ("rot_x", "rot_y", "rot_z"))))
    assert rot < 1.5
    # negative control: the rotation-only fit of the same tracks is refused (it does not
    # converge: no calibration written) or far off
    out0 = tmp_path / "none" / "calib.yaml"
    rc = main(["calibrate", str(driving), "--out", str(out0), "--translation", "none"])
    if rc != 0:
        assert not out0.exists()
        d0 = json.loads(out0.with_name("calib.failed.summary.json").read_text())
    else:
        d0 = _summary(out0)
    e0 = d0["error_vs_truth"]
    rot0 = math.degrees(math.sqrt(sum(e0[k] ** 2 for k in ("rot_x", "rot_y", "rot_z"))))
    assert abs(e0["fx"]) / tru["fx"] > 0.05 and rot0 > 5 * rot
    assert d0["translation"]["mode"] == "none"


def test_free_epipole_per_pair_is_selectable(driving, tmp_path) -> None:
    out = tmp_path / "pp" / "calib.yaml"
    assert main(["calibrate", str(driving), "--out", str(out), "--translation", "per-pair"]) == 0
    d = _summary(out)
    assert d["translation"]["mode"] == "per-pair" and d["translation"]["chosen_by"] == "option"
    assert len(d["translation"]["epipoles"]) == 29  # one per frame pair
    assert d["holdout_all"]["n"] > 0
    assert abs(d["error_vs_truth"]["timeshift_s"]) < 1.5e-3


def test_translation_nuisance_is_refused_on_laser_sessions(tmp_path, capsys) -> None:
    from tests.calib.test_calib_commands import _write_session

    s, _ = _write_session(tmp_path / "laser")
    out = tmp_path / "c" / "calib.yaml"
    assert main(["calibrate", str(s), "--out", str(out), "--translation", "per-pair"]) == 2
    assert "applies to natural-scene sessions" in capsys.readouterr().err
    assert not out.exists()


def test_cli_offers_every_translation_model() -> None:
    """The CLI spells the choices out (no CasADi import at parse time); they must be the
    library's, ``travel`` included."""
    import argparse

    from calib.natural.cli import add_natural_args
    from calib.natural.motion import TRANSLATIONS

    p = argparse.ArgumentParser()
    add_natural_args(p)
    (action,) = [a for a in p._actions if a.dest == "translation"]
    assert tuple(action.choices) == TRANSLATIONS
    assert p.parse_args(["--translation", "travel"]).translation == "travel"
