"""The session's calibration error fitted from the image's quality_ok streaks
(``blurtrack.detect.gyro.sessioncalib``): truth from the blur model through a known
calibration, and negative controls."""

from __future__ import annotations

import numpy as np

from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.sessioncalib import (
    CALIBRATION_STEPS,
    PARAMETERS,
    corrected_model,
    difference,
    fit_session_calibration,
)
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace

W, H = 640, 480
F = 500.0
EXP = 0.03
TIMES = (0.05, 0.11, 0.17)


def _model(R_cam_imu: np.ndarray, f: float, cx: float, cy: float, bias: float = 0.0) -> BlurModel:
    """A shake turning on all three axes (rad/s varying in time), seen through a calibration
    with a rolling shutter."""
    cam = Camera(resolution=(W, H), intrinsics=(f, f, cx, cy), readout_s=0.02)
    t = np.arange(0.0, 0.3, 1e-4)
    omega = np.stack(
        [0.9 * np.sin(9 * t) + 0.3, 0.7 * np.cos(7 * t), 2.0 * np.sin(5 * t + 1.0)], axis=1
    )
    calib = Calibration(
        camera=cam, R_cam_imu=R_cam_imu, gyro_bias_radps=np.array([bias, -bias, 0.0])
    )
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def _rot(axis: list[float], deg: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = np.deg2rad(deg)
    return np.asarray(np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K)


TRUE = _model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2)
#: Axes 0.8 degree, focal length 2 %, principal point 8 px and the bias 0.02 rad/s off.
INIT = _model(_rot([1.0, 1.0, 0.3], 0.8), 1.02 * F, W / 2 + 8, H / 2 - 8, bias=0.02)


def _grid(n: int) -> np.ndarray:
    gx, gy = np.meshgrid(np.linspace(30, W - 30, n), np.linspace(30, H - 30, n))
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _vectors(model: BlurModel, mids: np.ndarray, t_s: float) -> np.ndarray:
    pts = predict_curves(model, mids, t_s, EXP, 2).pts
    return np.asarray(pts[:, -1] - pts[:, 0])


def _frame(mids: np.ndarray, v: np.ndarray, ok: np.ndarray) -> FrameStreaks:
    """Streaks with midpoints ``mids`` and start-to-end vectors ``v``, ``ok`` quality_ok."""
    n = len(mids)
    return FrameStreaks(
        shape=(H, W),
        end_a=mids - v / 2,
        end_b=mids + v / 2,
        time_mid=mids.copy(),
        plateau=np.ones((n, 2)),
        length_px=np.hypot(*v.T),
        width_px=np.full(n, 2.0),
        snr=np.full(n, 50.0),
        points=[np.stack([mids[i] - v[i] / 2, mids[i] + v[i] / 2]) for i in range(n)],
        profile=[np.ones(2) for _ in range(n)],
        flags={c: np.zeros(n, bool) for c in FLAG_NAMES},
        sigma_c_px=1.5,
        noise=0.01,
        hot_pixels=0,
        quality=(np.zeros(n), np.zeros(n, bool), ok, np.full(n, "point", object)),
    )


def _session(model: BlurModel, n: int = 6, wrong_px: float = 0.0):
    """Three frames of ``n x n`` streaks whose vectors ``model`` draws, every other one with
    its vector flipped (the fit is orientation-free); with ``wrong_px``, as many more streaks
    ``wrong_px`` off that are not quality_ok."""
    frames, timings = [], []
    mids = _grid(n)
    for t_s in TIMES:
        v = _vectors(model, mids, t_s)
        v[::2] *= -1.0
        ok = np.ones(len(v), bool)
        if wrong_px:
            mids2 = np.concatenate([mids, mids + 3.0])
            v = np.concatenate([v, v + wrong_px])
            ok = np.concatenate([ok, np.zeros(len(ok), bool)])
            frames.append(_frame(mids2, v, ok))
        else:
            frames.append(_frame(mids, v, ok))
        timings.append(FrameTiming(t_s, EXP))
    return frames, timings


def test_difference_names_the_change_in_physical_units() -> None:
    d = np.array([2.0, -1.0, 3.0, 0.5, -0.2, 0.1, 1.5, -2.0, 0.3, -0.4, 0.6])
    got = difference(INIT.calib, corrected_model(INIT, d).calib)
    s = CALIBRATION_STEPS
    want = [s["focal"] * 2.0, -s["pp"], 3 * s["pp"], *(s["axes"] * d[3:6])]
    want += [s["time"] * 1.5, -2.0 * s["time"], *(s["bias"] * d[8:11])]
    assert list(got) == list(PARAMETERS)
    assert np.allclose(list(got.values()), want, atol=1e-9)


def test_the_fit_finds_the_calibration_that_draws_the_streaks() -> None:
    frames, timings = _session(TRUE, wrong_px=6.0)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "fitted"
    assert fit.voters == 3 * 36  # the quality_ok streaks only
    assert fit.residual_before_px > 0.5
    assert fit.residual_after_px < 0.01
    # Held out: streaks elsewhere in the frame and at another time, through the fitted
    # calibration, against the true one.
    fitted = BlurModel(fit.calib, TRUE.gyro, gyro_upsample=1)
    mids = _grid(9) + 7.0
    for t_s in (0.08, 0.2):
        err = np.hypot(*(_vectors(fitted, mids, t_s) - _vectors(TRUE, mids, t_s)).T)
        assert np.max(err) < 0.05
        before = np.hypot(*(_vectors(INIT, mids, t_s) - _vectors(TRUE, mids, t_s)).T)
        assert np.median(before) > 0.5
    assert abs(fit.change["focal_rel"] - (1 / 1.02 - 1)) < 0.005


def test_no_fit_without_enough_voters_or_where_nothing_is_gained() -> None:
    frames, timings = _session(TRUE, n=3)  # 27 voters for 11 unknowns (33 needed)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "too_few_voters"
    assert fit.calib is INIT.calib
    assert set(fit.change.values()) == {0.0}
    # Streaks drawn by the initial calibration itself: nothing to correct.
    frames, timings = _session(INIT)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "not_better"
    assert fit.calib is INIT.calib
    # Frames not covered are not read.
    fit = fit_session_calibration(frames, timings, [], INIT)
    assert fit.status == "too_few_voters" and fit.voters == 0


def test_a_correction_far_outside_the_linearisation_is_refused() -> None:
    # Streaks drawn through axes turned 25 degrees from the initial calibration's: the fit
    # predicts them (0.27 px), but a move of 0.4 rad (40 steps) says the start is wrong in
    # kind; the calibration is kept as given and the refused change reported.
    turned = _model(_rot([0.3, 1.0, 0.2], 25.0), F, (W - 1) / 2, (H - 1) / 2)
    frames, timings = _session(turned)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "implausible"
    assert fit.calib is INIT.calib
    assert max(abs(fit.change[k]) for k in ("axis_x_rad", "axis_y_rad", "axis_z_rad")) > 0.2
    # The same within reach (the test above): fitted.
    frames, timings = _session(TRUE)
    assert fit_session_calibration(frames, timings, [0, 1, 2], INIT).status == "fitted"
