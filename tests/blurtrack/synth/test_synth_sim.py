"""Simulator check: synthesising the simulator's sharp laser-grid frame with the session's
gyro and true calibration reproduces the simulator's blurred frame (streak ends within 0.2 px).

The simulator (rigs/sim) renders streaks analytically (time-integrated Gaussian splats, row by
row); the synthesiser warps the simulator's *sharp* frame along BlurModel's trajectories. Both
frames go through the same endpoint estimator (half maximum along each end's tangent), so the
comparison isolates the synthesis.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.session import load_session
from blurtrack.synth.render import render_blur

sim_rig = pytest.importorskip("rigs.sim.rig", reason="rigs/sim (the simulator) not installed")
sim_preset = pytest.importorskip("rigs.sim.preset")
sim_writer = pytest.importorskip("rigs.sim.writer")

BACK_PX = 4.0


def end_profile(img: np.ndarray, path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Profile of ``img`` along the tangent at the last point of ``path`` (inwards < 0)."""
    E = path[-1]
    dist = np.linalg.norm(path - E, axis=1)
    k = np.flatnonzero(dist >= BACK_PX)
    d = E - path[k[-1]]
    d /= np.linalg.norm(d)
    s = np.arange(-BACK_PX, 6.0, 0.02)
    q = (E[None] + s[:, None] * d[None]).astype(np.float32)
    return s, cv2.remap(img, q[None, :, 0], q[None, :, 1], cv2.INTER_CUBIC)[0]


def half_max(s: np.ndarray, prof: np.ndarray) -> float:
    """Where the profile falls to half its value 3 px inside the streak (px along the tangent)."""
    half = 0.5 * np.interp(-3.0, s, prof)
    i = np.flatnonzero((prof[:-1] >= half) & (prof[1:] < half))[-1]
    return float(np.interp(half, [prof[i + 1], prof[i]], [s[i + 1], s[i]]))


@pytest.mark.parametrize(
    ("preset", "changes"),
    [
        ("clean", {"exposure_s": 0.03, "synthetic_rms_radps": (2.0, 2.0, 0.6)}),
        ("realistic", {"motion_scale": (2.0, 2.0), "read_noise_e": 0.0, "shot_noise": False}),
    ],
)
def test_synthesis_reproduces_simulated_frame(
    tmp_path: Path, shared_data: Path, preset: str, changes: dict
) -> None:
    # Images without noise, 16 bits, and dots that do not saturate the sharp frame; the gyro
    # keeps the preset's noise, bias, misalignment and time offset (the realistic preset: a
    # rolling shutter, 200 Hz gyro and real hand shake).
    p = dataclasses.replace(
        sim_preset.get_preset(preset),
        width=640,
        height=360,
        focal_px=500.0,
        dot_flux_eps=4e6,
        ambient_eps=0.0,
        bit_depth=16,
        **changes,
    )
    rig = sim_rig.SimRig(p, seed=3, n_frames=2)
    sim_writer.write_session(rig, tmp_path / "s")
    session = load_session(tmp_path / "s")
    calib = calibration_from_dict(session.truth["calibration"])
    model = BlurModel(calib, session.gyro())
    frame = session.truth["frames"][1]
    t_ref = frame["t_ref_ns"] * 1e-9
    assert t_ref == pytest.approx(
        model.default_reference_time(frame["timestamp_ns"] * 1e-9, p.exposure_s), abs=1e-9
    )
    sharp = rig.render_sharp(t_ref, noise=False).astype(np.float32)
    res = render_blur(
        sharp, model, frame["timestamp_ns"] * 1e-9, float(session.exposures_s[1]), t_ref
    )
    sim = session.read_image(1).astype(np.float32)
    assert res.blur[res.valid].sum() == pytest.approx(sim[res.valid].sum(), rel=0.01)
    errors = []
    for st in frame["streaks"]:
        if not st["inside"] or st["length_px"] < 10:
            continue
        line = np.asarray(st["centerline"], float)
        for path in (line[::-1], line):  # the start, then the end
            errors.append(
                half_max(*end_profile(res.blur, path)) - half_max(*end_profile(sim, path))
            )
    assert len(errors) >= 20
    assert np.max(np.abs(errors)) < 0.2


def test_predict_heat_maps_point_streak_ends_to_their_dots(
    tmp_path: Path, shared_data: Path
) -> None:
    # blurtrack predict on a simulated recording with its true calibration: at every true
    # streak start x, x + q(0) is the dot's position at the reference time (same at the end).
    from blurtrack.synth.predict import predict_session

    p = dataclasses.replace(
        sim_preset.get_preset("realistic"), width=640, height=360, focal_px=500.0
    )
    rig = sim_rig.SimRig(p, seed=5, n_frames=2)
    sim_writer.write_session(rig, tmp_path / "s")
    session = load_session(tmp_path / "s")
    calib = calibration_from_dict(session.truth["calibration"])
    res = predict_session(session, calib, tmp_path / "p", stride=4)
    assert res.skipped == []
    errors = []
    for frame in session.truth["frames"]:
        heat = np.load(tmp_path / "p" / "heat" / f"{frame['timestamp_ns']}.npy")
        for st in frame["streaks"]:
            if not st["inside"]:
                continue
            for key, ch in (("start", 0), ("end", 2)):
                x = np.asarray(st[key], np.float32)
                q = [
                    cv2.remap(heat[c], x[None, None, :1], x[None, None, 1:], cv2.INTER_LINEAR)[0, 0]
                    for c in (ch, ch + 1)
                ]
                errors.append(np.linalg.norm(x + np.asarray(q) - np.asarray(st["ref"])))
    assert len(errors) > 100
    # The session's gyro is noisy (5 mrad/s), biased (removed by the true calibration) and
    # sampled at 200 Hz; the prediction still lands within a tenth of a pixel.
    assert np.max(errors) < 0.1, np.max(errors)
