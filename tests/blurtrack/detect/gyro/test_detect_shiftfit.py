"""The time shift and readout refined by the predicted templates (blurtrack.detect.gyro.shiftfit),
on an exactly rendered rolling-shutter frame of arcs: the gyro's rate turns within the
exposure, so a wrong shift bends the predicted curves the wrong way, and a wrong readout
does so by a different amount in every row."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from blurtrack.detect import detect_frame
from blurtrack.detect.gyro import shiftfit
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.testing.streak_frames import quantise, render_streaks

W, H = 640, 480
F = 500.0
T0, EXP = 0.05, 0.03
READOUT_S = 0.024


def _model(shift_s: float, readout_s: float, turning: bool = True) -> BlurModel:
    """A rate of 1.6 rad/s (~27 px per exposure) whose direction turns by a right angle per
    exposure (``turning``), or a constant one."""
    cam = Camera(
        resolution=(W, H), intrinsics=(F, F, (W - 1) / 2, (H - 1) / 2), readout_s=readout_s
    )
    t = np.arange(0.0, 0.2, 1e-3)
    phase = (0.5 * np.pi / EXP) * t if turning else 0.0 * t
    omega = 1.6 * np.stack([np.cos(phase), np.sin(phase), 0.0 * t], axis=1)
    calib = Calibration(camera=cam, R_cam_imu=np.eye(3), timeshift_cam_imu_s=shift_s)
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def _frame(model: BlurModel) -> np.ndarray:
    """Arcs on a 6 x 5 grid over the whole frame (every row band), as ``model`` draws them."""
    gx, gy = np.meshgrid(70.0 + 100.0 * np.arange(6), 50.0 + 95.0 * np.arange(5))
    dots = np.stack([gx.ravel(), gy.ravel()], axis=1)
    curves = predict_curves(model, dots, T0, EXP, samples=801).pts
    image = render_streaks((H, W), list(curves), flux_per_px=0.5, sigma_px=1.3, noise=0.004)
    return quantise(image)


@pytest.fixture(scope="module")
def arcs():
    image = _frame(_model(0.0, READOUT_S))
    return image, detect_frame(image)


def _refine(image, fs, model, monkeypatch, params=None):
    # The gate is the template pass's business (tested there): here every frame goes through.
    monkeypatch.setattr(shiftfit, "gate", lambda *a: False)
    return shiftfit.refine_timeshift(
        lambda k: image, [fs], [FrameTiming(T0, EXP)], [0], model, params or DetectParams()
    )


def test_the_templates_find_the_true_shift_and_readout(arcs, monkeypatch) -> None:
    image, fs = arcs
    assert shiftfit.usable_streaks(fs).size >= 25  # the arcs are found one by one
    # the guess: 1.5 ms late, the readout 10 % short
    got = _refine(image, fs, _model(0.0015, 0.9 * READOUT_S), monkeypatch)
    assert got.status == "refined" and got.n_streaks >= 25
    assert abs(got.timeshift_s) < 0.3e-3
    assert abs(got.readout_s - READOUT_S) < 0.8e-3
    # negative control: the shift alone (no readout fitted) settles for the middle row's,
    # off the truth at row 0 by about half the readout's error
    p = DetectParams()
    no_readout = replace(p, timeshift=replace(p.timeshift, min_row_spread=2.0))
    alone = _refine(image, fs, _model(0.0015, 0.9 * READOUT_S), monkeypatch, no_readout)
    assert alone.status == "refined" and alone.readout_s == pytest.approx(0.9 * READOUT_S)
    assert abs(alone.timeshift_s) > 0.8e-3


def test_a_gyro_that_never_turns_does_not_tell_shifts_apart(monkeypatch) -> None:
    # A constant rate draws the same straight streak at every shift: the score is flat, and
    # the scan's shift and the session's readout are kept.
    model = _model(0.0015, READOUT_S, turning=False)
    image = _frame(_model(0.0, READOUT_S, turning=False))
    got = _refine(image, detect_frame(image), model, monkeypatch)
    assert got.status == "flat"
    assert got.timeshift_s == 0.0015 and got.readout_s == READOUT_S


def test_a_guess_beyond_the_grid_is_not_refined(arcs, monkeypatch) -> None:
    image, fs = arcs
    got = _refine(image, fs, _model(0.006, READOUT_S), monkeypatch)  # 6 ms off, the grid 3
    assert got.status == "at the grid's edge" and got.timeshift_s == 0.006


def test_frames_the_gate_skips_are_not_decoded(arcs) -> None:
    _, fs = arcs

    def never(k: int) -> np.ndarray:
        raise AssertionError("decoded")

    # the truth's own model: every first-pass streak matches its prediction, the gate skips
    got = shiftfit.refine_timeshift(
        never, [fs], [FrameTiming(T0, EXP)], [0], _model(0.0, READOUT_S), DetectParams()
    )
    assert got.status == "not needed" and got.timeshift_s == 0.0


def test_the_fit_recovers_a_shift_and_readout_between_the_trials() -> None:
    # Streaks in every row band, each scored by a parabola peaking at its own row's shift
    # (0.31 ms at the middle row, readout change 1.3 ms): both between the fine grid's steps
    # by less than a step; a linear interpolation would draw them to the trials.
    g = np.arange(-3.0, 3.0 + 1e-9, 0.375)
    u = np.linspace(0.05, 0.95, 40)
    sc = -((g[:, None] - (0.31 + 1.3 * (u - 0.5))[None, :]) ** 2)
    m, dr, edge = shiftfit.fit_shift_readout(g, sc, u, 4.0)
    assert not edge
    assert abs(m - 0.31) <= shiftfit.FIT_STEP_MS / 2 + 1e-9
    assert abs(dr - 1.3) <= shiftfit.READOUT_STEP_MS / 2 + 1e-9
    m0, dr0, _ = shiftfit.fit_shift_readout(g, sc, u, 0.0)
    assert dr0 == 0.0 and abs(m0 - 0.31) <= shiftfit.FIT_STEP_MS  # the shift alone: the middle
