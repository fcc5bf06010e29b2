"""The natural-scene simulator (rigs.sim.natural): session layout, truth, and the rendered
geometry checked against the true motion by tracking."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.features.tracks import to_gray8, track_pair
from blurtrack.io.session import load_session
from rigs.sim.errors import SimError
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

SMALL = dict(width=320, height=180, focal_px=250.0)


@pytest.fixture(scope="module")
def rig(shared_data) -> NaturalRig:
    return NaturalRig(get_preset("realistic").replace(**SMALL), 2, 6)


def test_session_is_natural_with_truth(rig: NaturalRig, tmp_path) -> None:
    write_session(rig, tmp_path / "s")
    s = load_session(tmp_path / "s")
    assert s.meta.target_kind == "natural"
    assert len(s.frames) == 6 and s.truth["simulator"]["scene"]["kind"] == "natural"
    assert s.truth["calibration"]["cam0"]["readout_s"] == pytest.approx(rig.camera.readout_s)
    a, b = s.read_image(0), s.read_image(1)
    assert a.shape == (180, 320) and a.std() > 10 and np.abs(a.astype(int) - b).mean() > 1


def test_sharp_views_move_as_the_true_rotation_says(rig: NaturalRig) -> None:
    t0, t1 = 1.0, 1.03
    A = to_gray8(rig.render_sharp(t0))
    B = to_gray8(rig.render_sharp(t1))
    pa, pb, _ = track_pair(A, B)
    assert len(pa) > 50
    cam = rig.camera
    R0, R1 = rig.motion.orientation(np.array([t0, t1]))
    w = cam.unproject(pa) @ R0.T  # world directions R_c(t0) K^-1 x
    pred = cam.project(w @ R1)  # seen at t1 through R_c(t1)^T
    err = np.linalg.norm(pb - pred, axis=1)
    assert np.median(np.linalg.norm(pb - pa, axis=1)) > 2  # it did move
    assert np.median(err) < 0.1


def test_distortion_and_missing_background_are_refused(tmp_path) -> None:
    p = get_preset("realistic").replace(**SMALL)
    with pytest.raises(SimError, match="distortion"):
        NaturalRig(p.replace(distortion_coeffs=(0.1, 0.0, 0.0, 0.0)), 0, 2)
    with pytest.raises(SimError, match="does not exist"):
        NaturalRig(p, 0, 2, background=tmp_path / "none.jpg")


def test_simulate_command_target_natural(tmp_path, capsys, shared_data) -> None:
    from blurtrack.cli import main

    preset = tmp_path / "p.yaml"
    preset.write_text("base: realistic\nwidth: 160\nheight: 90\nfocal_px: 125.0\n")
    out = tmp_path / "s"
    argv = ["simulate", str(out), "--target", "natural", "--preset-file", str(preset)]
    assert main([*argv, "--frames", "3"]) == 0
    assert load_session(out).meta.target_kind == "natural"
    assert main(["simulate", str(tmp_path / "l"), "--background", str(preset)]) == 2
    assert "--target natural" in capsys.readouterr().err


def test_plane_at_depth_with_forward_motion_renders_the_true_parallax(shared_data) -> None:
    p = get_preset("realistic").replace(**SMALL)
    far = NaturalRig(p, 2, 6)
    still = NaturalRig(p, 2, 6, depth_m=5.0)
    # a camera at the origin sees a plane at any depth as the far plane
    assert np.array_equal(far.render_sharp(1.0), still.render_sharp(1.0))
    drive = NaturalRig(p, 2, 6, depth_m=5.0, speed_mps=4.0)
    t0, t1 = 1.0, 1.03
    A, B = (to_gray8(drive.render_sharp(t)) for t in (t0, t1))
    pa, pb, _ = track_pair(A, B)
    assert len(pa) > 50
    cam = drive.camera
    R0, R1 = drive.motion.orientation(np.array([t0, t1]))
    c0, c1 = drive.position(np.array([t0, t1]))
    w = cam.unproject(pa) @ R0.T
    X = c0 + w * ((5.0 - c0[2]) / w[:, 2])[:, None]  # where each ray meets the plane
    pred = cam.project((X - c1) @ R1)
    rot_only = cam.project(w @ R1)
    assert np.median(np.linalg.norm(pb - pred, axis=1)) < 0.1
    # negative control: the zoom of forward motion is visible against pure rotation
    assert np.median(np.linalg.norm(pb - rot_only, axis=1)) > 0.5
    assert drive.simulator_info()["scene"]["speed_mps"] == 4.0


def test_driving_options_are_checked(shared_data) -> None:
    p = get_preset("realistic").replace(**SMALL)
    with pytest.raises(SimError, match="finite depth"):
        NaturalRig(p, 0, 2, speed_mps=1.0)
    with pytest.raises(SimError, match="positive distance"):
        NaturalRig(p, 0, 2, depth_m=-1.0)
    with pytest.raises(SimError, match="half way"):
        NaturalRig(p, 0, 60, depth_m=2.0, speed_mps=5.0)
