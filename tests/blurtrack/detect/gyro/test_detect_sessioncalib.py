"""The session's calibration error fitted from the image's quality_ok streaks
(``blurtrack.detect.gyro.sessioncalib``): truth from the blur model through a known
calibration, and negative controls."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks
from blurtrack.detect.gyro.calibsteps import (
    CALIBRATION_STEPS,
    PARAMETERS,
    SCALE_TERMS,
    corrected_model,
    difference,
)
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.sessioncalib import (
    SCALE_PRIOR,
    fit_sample,
    fit_session_calibration,
    fit_system,
    sample_points,
    sample_vectors,
    session_fit,
    session_residual,
)
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import ConfigError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace

W, H = 640, 480
F = 500.0
EXP = 0.03
TIMES = (0.05, 0.11, 0.17)


def _model(
    R_cam_imu: np.ndarray,
    f: float,
    cx: float,
    cy: float,
    bias: float = 0.0,
    M: np.ndarray | None = None,
) -> BlurModel:
    """A shake turning on all three axes (rad/s varying in time), seen through a calibration
    with a rolling shutter (``M``: the gyro's scale matrix, the identity if None)."""
    cam = Camera(resolution=(W, H), intrinsics=(f, f, cx, cy), readout_s=0.02)
    t = np.arange(0.0, 1.0, 1e-4)
    omega = np.stack(
        [0.9 * np.sin(9 * t) + 0.3, 0.7 * np.cos(7 * t), 2.0 * np.sin(5 * t + 1.0)], axis=1
    )
    calib = Calibration(
        camera=cam,
        R_cam_imu=R_cam_imu,
        gyro_bias_radps=np.array([bias, -bias, 0.0]),
        gyro_scale_matrix=np.eye(3) if M is None else M,
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


def _session(model: BlurModel, n: int = 6, wrong_px: float = 0.0, times: tuple[float, ...] = TIMES):
    """Frames (at ``times``, three by default) of ``n x n`` streaks whose vectors ``model``
    draws, every other one with its vector flipped (the fit is orientation-free); with
    ``wrong_px``, as many more streaks ``wrong_px`` off that are not quality_ok."""
    frames, timings = [], []
    mids = _grid(n)
    for t_s in times:
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
    d = np.concatenate([d, [1.5, -0.5, 0.8, 0.3, -1.2, 0.7]])
    got = difference(INIT.calib, corrected_model(INIT, d).calib)
    s = CALIBRATION_STEPS
    want = [s["focal"] * 2.0, -s["pp"], 3 * s["pp"], *(s["axes"] * d[3:6])]
    want += [s["time"] * 1.5, -2.0 * s["time"], *(s["bias"] * d[8:11]), *(s["scale"] * d[11:])]
    assert list(got) == list(PARAMETERS)
    assert np.allclose(list(got.values()), want, atol=1e-9)


def test_the_fit_finds_the_calibration_that_draws_the_streaks() -> None:
    frames, timings = _session(TRUE, wrong_px=6.0)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "fitted"
    assert fit.voters == 3 * 36  # the quality_ok streaks only
    assert fit.residual_before_px > 0.5
    # Two Gauss-Newton rounds over the 17 unknowns (the axes, the bias and the gyro's scale
    # terms trade off over three frames): 0.015 px; a third round would give 2e-4.
    assert fit.residual_after_px < 0.02
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
    frames, timings = _session(TRUE, n=4)  # 48 voters for 17 unknowns (51 needed)
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


#: A gyro whose scale factors are 2 % off and whose axes feel 1.5-2 % of each other's rates
#: (a MEMS gyro's datasheet spread); symmetric, as the fit's terms (the antisymmetric part
#: of a scale matrix is a turn of the axes).
SCALED = np.array([[1.02, 0.015, -0.02], [0.015, 0.985, 0.018], [-0.02, 0.018, 1.01]])


def test_the_fit_finds_the_gyros_scale_and_cross_axis_terms() -> None:
    true = _model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2, M=SCALED)
    # Eight frames over the shake, whose rates turn about every axis.
    frames, timings = _session(true, times=tuple(np.linspace(0.05, 0.9, 8)))
    fit = fit_session_calibration(frames, timings, list(range(8)), INIT)
    assert fit.status == "fitted"
    assert fit.residual_after_px < 0.01
    got = np.asarray(fit.calib.gyro_scale_matrix)
    np.testing.assert_allclose(0.5 * (got + got.T), SCALED, atol=2e-3)
    fitted = BlurModel(fit.calib, true.gyro, gyro_upsample=1)
    mids = _grid(9) + 7.0
    err = np.hypot(*(_vectors(fitted, mids, 0.5) - _vectors(true, mids, 0.5)).T)
    assert np.max(err) < 0.05
    # Negative control: the same streaks fitted without the scale terms (their columns
    # dropped from the Jacobian) stay 20x further off.
    system = fit_system(frames, timings, INIT)
    assert system is not None
    m, p, J = system
    voters = np.ones(len(m), bool)
    r_all, _ = session_residual(m, p, J, voters)
    r_less, _ = session_residual(m, p, J[:, :, : len(PARAMETERS) - len(SCALE_TERMS)], voters)
    assert np.median(r_less) > 20 * np.median(r_all)


def test_the_scale_prior_holds_a_fit_its_frames_barely_determine() -> None:
    # Three frames of the same shake: the scale terms trade off with the axes and the bias
    # (their vectors nearly the same). With the prior the fit stays near nominal and draws the
    # streaks; without it, it runs the scale matrix off to one no gyro has (refused, the
    # calibration kept as given).
    true = _model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2, M=SCALED)
    frames, timings = _session(true)
    fit = fit_session_calibration(frames, timings, [0, 1, 2], INIT)
    assert fit.status == "fitted"
    got = np.asarray(fit.calib.gyro_scale_matrix)
    assert np.max(np.abs(got - np.eye(3))) < 3 * SCALE_PRIOR
    fitted = BlurModel(fit.calib, true.gyro, gyro_upsample=1)
    mids = _grid(9) + 7.0
    err = np.hypot(*(_vectors(fitted, mids, 0.15) - _vectors(true, mids, 0.15)).T)
    assert np.max(err) < 0.05
    loose = fit_session_calibration(frames, timings, [0, 1, 2], INIT, scale_prior=np.inf)
    assert loose.status != "fitted" and loose.calib is INIT.calib
    # The run-off correction itself is one no calibration holds: no fit, rather than an error
    # where the check applies it.
    system = fit_system(frames, timings, INIT)
    assert system is not None
    m, p, J = system
    _, e = session_residual(m, p, J, np.ones(len(m), bool))  # no prior: the first-order fit
    with pytest.raises(ConfigError):
        corrected_model(INIT, e)
    assert session_fit(frames, timings, INIT, max_steps=None, scale_prior=np.inf) is None


def test_the_scale_prior_is_centred_on_the_nominal_gyro() -> None:
    # A second fit from an already corrected model (the check's, after the template pass)
    # holds the scale terms to the nominal gyro's, not to where the first fit left them: its
    # prior's centre is minus that first move, in steps; the other parameters have none.
    from blurtrack.detect.gyro.sessioncalib import _scale_prior

    e = np.zeros(len(PARAMETERS))
    e[-len(SCALE_TERMS) :] = [1.5, -0.5, 0.8, 0.3, -1.2, 0.7]
    moved = corrected_model(INIT, e)
    centre, sigma = _scale_prior(moved, INIT.calib)
    np.testing.assert_allclose(centre, -e, atol=1e-9)
    k = len(PARAMETERS) - len(SCALE_TERMS)
    assert np.all(np.isinf(sigma[:k]))
    np.testing.assert_allclose(sigma[k:], SCALE_PRIOR / CALIBRATION_STEPS["scale"])
    # Without a nominal calibration: centred on the model's own.
    assert not np.any(_scale_prior(moved, None)[0])
    # A sigma of its own, relative; none that is not positive.
    np.testing.assert_allclose(
        _scale_prior(moved, None, 0.05)[1][k:], 0.05 / CALIBRATION_STEPS["scale"]
    )
    for bad in (0.0, -0.01, np.nan):
        with pytest.raises(ValueError, match="scale prior"):
            _scale_prior(moved, None, bad)


def test_the_sample_points_are_the_streaks_one_call_predicts() -> None:
    # The fit predicts the same sample 38 times: its points are gathered once, with the very
    # values of each frame's streaks (a negative control: another frame's time differs).
    frames, timings = _session(TRUE, wrong_px=6.0)
    pos, picks = fit_sample(frames)
    ref, ft, ex = sample_points(frames, timings, pos, picks)
    assert len(ref) == len(ft) == len(ex) == 3 * 36
    for j, (k, s) in enumerate(zip(pos, picks, strict=True)):
        rows = slice(36 * j, 36 * (j + 1))
        assert np.array_equal(ref[rows], frames[k].time_mid[s])
        assert np.all(ft[rows] == timings[k].t_s) and np.all(ex[rows] == EXP)
    assert ft[0] != ft[-1]
    once = sample_vectors(frames, timings, INIT, pos, picks)
    given = sample_vectors(frames, timings, INIT, pos, picks, (ref, ft, ex))
    assert np.array_equal(once, given)
    assert np.allclose(once[:36], _vectors(INIT, frames[0].time_mid[picks[0]], TIMES[0]))
