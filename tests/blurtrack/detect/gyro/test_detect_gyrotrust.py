"""The gyro's check of quality_ok ends (blurtrack.detect.gyro.gyrotrust) on exactly rendered
frames: a shake that turns shortly before the end of the exposure draws streaks whose visible
end is the turn, not the end (a shallow hairpin the image cannot see); a shake that does not
turn (the negative control) keeps its quality_ok streaks."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.gyro.calibsteps import PARAMETERS, corrected_model, perturbed_models
from blurtrack.detect.gyro.framecheck import (
    MIN_VOTERS,
    GyroCheck,
    apply_check,
    check_frame,
    frame_tolerances,
    hairpin_depth,
    vector_residual,
)
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.gyrotrust import PATH_SAMPLES
from blurtrack.detect.gyro.sessioncalib import MAX_FIT_STEPS, fit_sample, session_residual
from blurtrack.detect.separation.quality import REASONS, frame_quality
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.testing.streak_frames import quantise, render_streaks

W, H = 480, 360
F = 400.0
T0, EXP = 0.05, 0.04
#: The dot's excursion scale (px): x(tau) = REACH_PX sin(pi tau / (2 TURN)) over the exposure.
REACH_PX = 24.0
#: Issue 45's end gate (px).
GATE_PX = 2.0


def _model(turn: float, reach_px: float = REACH_PX) -> BlurModel:
    """A rotation about y whose rate ``cos(pi tau / (2 turn))`` reaches zero at ``tau = turn``
    of the exposure (``turn >= 1``: no reversal), no rolling shutter; ``reach_px``: the
    excursion scale."""
    cam = Camera(resolution=(W, H), intrinsics=(F, F, (W - 1) / 2, (H - 1) / 2), readout_s=0.0)
    t = np.arange(0.0, 0.2, 1e-4)
    tau = (t - T0) / EXP
    wy = reach_px * np.pi / (2.0 * turn * F * EXP) * np.cos(np.pi * tau / (2.0 * turn))
    omega = np.stack([0.0 * t, wy, 0.0 * t], axis=1)
    calib = Calibration(camera=cam, R_cam_imu=np.eye(3), timeshift_cam_imu_s=0.0)
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def _depth(turn: float) -> float:
    """Analytic depth of the end inside the turn: ``REACH (1 - sin(pi / (2 turn)))``."""
    return REACH_PX * (1.0 - np.sin(np.pi / (2.0 * turn))) if turn < 1.0 else 0.0


def _frame(
    model: BlurModel, spot_gap_px: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twelve dots on a 4 x 3 grid: the image and the true starts and ends. ``spot_gap_px``:
    also a still light (a round spot) that far beyond the end of the 2nd and 7th streaks."""
    dots = np.stack(np.meshgrid(80.0 + 100.0 * np.arange(4), 80.0 + 100.0 * np.arange(3)), -1)
    dots = dots.reshape(-1, 2)
    times = T0 + EXP * np.linspace(0.0, 1.0, 1200)
    tracks = model.point_track(dots, np.full(len(dots), T0 + EXP / 2), times)
    spots = []
    if spot_gap_px is not None:
        for i in (1, 6):
            u = tracks[i][-1] - tracks[i][0]
            u /= np.linalg.norm(u)
            spots.append(tracks[i][-1] + u * spot_gap_px + u * np.linspace(0.0, 0.5, 50)[:, None])
    image = render_streaks(
        (H, W),
        [*(tracks[i] for i in range(len(dots))), *spots],
        flux_per_px=0.6,
        sigma_px=1.3,
        noise=0.004,
        seed=5,
    )
    return quantise(image), tracks[:, 0], tracks[:, -1]


def _wrong(fs, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """``(N,)`` whether a detection's ends are not both within the gate of one true streak."""
    a, b = fs.end_a[:, None], fs.end_b[:, None]
    same = np.maximum(np.hypot(*(a - starts).T).T, np.hypot(*(b - ends).T).T)
    swap = np.maximum(np.hypot(*(a - ends).T).T, np.hypot(*(b - starts).T).T)
    return np.asarray(np.minimum(same, swap).min(axis=1) > GATE_PX)


def _checked(turn: float, reach_px: float = REACH_PX, spot_gap_px: float | None = None):
    model = _model(turn, reach_px)
    image, starts, ends = _frame(model, spot_gap_px)
    p = DetectParams()
    fs = detect_frame(image, p)
    fs.quality, fs.one_doubt = frame_quality(fs, p)
    curves = predict_curves(model, fs.time_mid, T0, EXP, PATH_SAMPLES).pts
    check = check_frame(fs, curves, np.asarray(fs.quality[2], bool))
    ok, reason = apply_check(fs, check, p.source)
    return fs, check, ok, reason, _wrong(fs, starts, ends)


def test_hairpin_depth_of_simple_paths() -> None:
    s = np.linspace(0.0, 1.0, 41)[:, None]
    straight = np.hstack([10.0 * s, 2.0 * s])
    out_back = np.hstack([np.where(s < 0.8, 12.5 * s, 10.0 - 2.5 * (s - 0.8) / 0.2), 0 * s])
    loop = np.hstack([np.sin(np.pi * s) * 6.0, 0 * s])  # out and back to the start
    d = hairpin_depth(np.stack([straight, out_back, loop]))
    assert d == pytest.approx([0.0, 2.5, 0.0], abs=1e-9)


def test_hairpin_depth_of_a_sideways_hook_is_the_distance_to_the_visible_end() -> None:
    """A path that starts 3 px below its line, runs up 3 px, back 1 px along it and then 10 px
    along it (a hook at the start, as a shake turning at the exposure's start draws it): the
    image's line ends at the hook's corner (-1, 0), the start lies sqrt(10) px from it. Along
    the chord alone (the former depth) it is 0.42 px inside, under the 0.5 px tolerance."""
    s = np.linspace(0.0, 1.0, 31)[:, None]
    hook = np.vstack([[0.0, 3.0], [0.0, 0.0], [-1.0, 0.0], [10.0, 0.0]])
    seg = np.hypot(*np.diff(hook, axis=0).T)
    at = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    path = np.hstack([np.interp(s, at, hook[:, 0]), np.interp(s, at, hook[:, 1])])
    d = hairpin_depth(path[None])[0]
    assert d == pytest.approx(np.sqrt(10.0), abs=0.05)
    chord = (path[-1] - path[0]) / np.hypot(*(path[-1] - path[0]))
    assert float(path[0] @ chord - np.min(path @ chord)) < 0.5  # the former, along the chord
    # A path bending sideways without doubling back along its chord: no depth.
    arc = np.hstack([10.0 * s, 3.0 * s**2])
    assert hairpin_depth(arc[None])[0] == pytest.approx(0.0, abs=1e-9)


def test_the_vector_residual_sees_an_end_off_through_a_common_similarity() -> None:
    rng = np.random.default_rng(3)
    p = rng.normal(0.0, 15.0, (40, 2))
    z = 1.03 * np.exp(1j * np.deg2rad(2.0))  # the initial calibration's scale and roll
    zm = z * (p[:, 0] + 1j * p[:, 1])
    m = np.stack([zm.real, zm.imag], axis=1) + rng.normal(0.0, 0.15, (40, 2))
    m[::2] *= -1.0  # orientation-free
    m[7] += [2.5, 0.0]  # one end 2.5 px off
    r = vector_residual(m, p, np.ones(40, bool))
    assert r[7] > 2.0
    assert np.all(np.delete(r, 7) < 1.0)
    assert np.all(np.isnan(vector_residual(m[:4], p[:4], np.ones(4, bool))))


def _shake_model(R_cam_imu: np.ndarray, f: float, cx: float, cy: float) -> BlurModel:
    """A strong three-axis shake (pan, tilt and roll) seen through a calibration."""
    cam = Camera(resolution=(W, H), intrinsics=(f, f, cx, cy), readout_s=0.0)
    t = np.arange(0.0, 0.2, 1e-4)
    omega = np.stack([0.9 + 0.0 * t, 0.6 + 0.0 * t, 2.5 + 0.0 * t], axis=1)  # rad/s
    calib = Calibration(camera=cam, R_cam_imu=R_cam_imu, timeshift_cam_imu_s=0.0)
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def _rot(axis: np.ndarray, deg: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = np.deg2rad(deg)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def test_the_session_fit_absorbs_a_calibration_error_that_varies_over_the_frame() -> None:
    # Truth from the model: the dots' vectors through the true calibration (m) and through an
    # initial one whose axes are tilted 1 degree, focal length 2 % and principal point 8 px
    # off (p). Their difference varies over the frame (a strong roll), so one similarity
    # leaves residuals above the tolerance on whole streaks; the calibration's first-order
    # fit (the Jacobian from the perturbed models) does not. Negative control: one end 2.5 px
    # off stands out.
    gx, gy = np.meshgrid(np.linspace(30, W - 30, 9), np.linspace(30, H - 30, 7))
    ref = np.stack([gx.ravel(), gy.ravel()], axis=1)
    true = _shake_model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2)
    init = _shake_model(_rot(np.array([1.0, 1.0, 0.0]), 1.0), 1.02 * F, W / 2 + 8, H / 2 - 8)

    def vectors(model: BlurModel) -> np.ndarray:
        pts = predict_curves(model, ref, T0, EXP, 9).pts
        return np.asarray(pts[:, -1] - pts[:, 0])

    m, p = vectors(true), vectors(init)
    J = np.stack([vectors(k) - p for k in perturbed_models(init)], axis=2)
    assert J.shape == (len(m), 2, len(PARAMETERS))
    voters = np.ones(len(m), bool)
    tol = DetectParams().source.gyro_vector_tol_px
    assert np.max(vector_residual(m, p, voters)) > tol  # a similarity rejects right streaks
    flip = m.copy()
    flip[::3] *= -1.0  # orientation-free
    r, d = session_residual(flip, p, J, voters)
    assert np.all(r < 0.5 * tol)
    assert abs(d[0] * 0.01 - (1.0 / 1.02 - 1.0)) < 0.01  # the focal length, to first order
    bad = m.copy()
    bad[11] += [0.0, 2.5]
    r, _ = session_residual(bad, p, J, voters)
    assert r[11] > tol
    assert np.all(np.delete(r, 11) < 0.5 * tol)
    # Too few voters for the 17 unknowns (three each): no fit.
    few = np.zeros(len(m), bool)
    few[: 3 * len(PARAMETERS) - 1] = True
    assert np.all(np.isnan(session_residual(m, p, J, few)[0]))


def _shake_vectors(model: BlurModel, ref: np.ndarray) -> np.ndarray:
    pts = predict_curves(model, ref, T0, EXP, 9).pts
    return np.asarray(pts[:, -1] - pts[:, 0])


def test_the_corrected_model_is_each_perturbed_model_at_a_unit_error() -> None:
    # d = 0: the model itself; d = e_i: the i-th perturbed model (the Jacobian's columns), to
    # the last bit, with a rolling shutter (the readout is a parameter) and a gyro bias.
    gx, gy = np.meshgrid(np.linspace(30, W - 30, 5), np.linspace(30, H - 30, 4))
    ref = np.stack([gx.ravel(), gy.ravel()], axis=1)
    base = _shake_model(_rot(np.array([1.0, 0.0, 1.0]), 2.0), F, W / 2 + 3, H / 2 - 2)
    calib = base.calib.with_(readout_s=0.02, gyro_bias_radps=(0.01, -0.02, 0.03))
    model = BlurModel(calib, base.gyro, gyro_upsample=1)
    # (Calibration.with_ re-normalises R_cam_imu: ~1e-13 px.)
    np.testing.assert_allclose(
        _shake_vectors(corrected_model(model, np.zeros(len(PARAMETERS))), ref),
        _shake_vectors(model, ref),
        rtol=0,
        atol=1e-9,
    )
    moved = perturbed_models(model)
    assert len(moved) == len(PARAMETERS)
    for i, mv in enumerate(moved):
        np.testing.assert_array_equal(
            _shake_vectors(corrected_model(model, np.eye(len(PARAMETERS))[i]), ref),
            _shake_vectors(mv, ref),
        )
    # A readout that the error would make negative is a global shutter's.
    assert corrected_model(model, -100.0 * np.eye(len(PARAMETERS))[7]).camera.readout_s == 0.0


def _varying_shake_model(R_cam_imu: np.ndarray, f: float, cx: float, cy: float) -> BlurModel:
    """A three-axis shake whose rates vary over the exposure (the axes and the bias apart)."""
    cam = Camera(resolution=(W, H), intrinsics=(f, f, cx, cy), readout_s=0.0)
    t = np.arange(0.0, 0.2, 1e-4)
    omega = np.stack(
        [0.9 + 2.0 * np.sin(60 * t), 0.6 - 1.5 * np.cos(45 * t), 2.5 * np.sin(30 * t + 1.0)],
        axis=1,
    )
    calib = Calibration(camera=cam, R_cam_imu=R_cam_imu, timeshift_cam_imu_s=0.0)
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def test_the_corrected_model_explains_the_streaks_the_session_fit_absorbed() -> None:
    # The session fit's calibration error applied to the initial calibration (all of it, not
    # only to first order): its predicted vectors match the true ones within a fifth of the
    # tolerance, and the fitted error is within MAX_FIT_STEPS.
    gx, gy = np.meshgrid(np.linspace(30, W - 30, 9), np.linspace(30, H - 30, 7))
    ref = np.stack([gx.ravel(), gy.ravel()], axis=1)
    true = _varying_shake_model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2)
    init = _varying_shake_model(
        _rot(np.array([1.0, 1.0, 0.0]), 1.0), 1.02 * F, W / 2 + 8, H / 2 - 8
    )
    # The dots of frames spread over the trace (as a session's): the rates differ.
    ft = np.linspace(0.005, 0.15, len(ref))

    def vectors(model: BlurModel) -> np.ndarray:
        pts = predict_curves(model, ref, ft, EXP, 2).pts
        return np.asarray(pts[:, -1] - pts[:, 0])

    m, p = vectors(true), vectors(init)
    J = np.stack([vectors(k) - p for k in perturbed_models(init)], axis=2)
    _, d = session_residual(m, p, J, np.ones(len(m), bool))
    assert np.max(np.abs(d)) < MAX_FIT_STEPS
    q = vectors(corrected_model(init, d))
    tol = DetectParams().source.gyro_vector_tol_px
    assert np.max(np.hypot(*(m - p).T)) > tol  # the initial calibration alone does not
    assert np.max(np.hypot(*(m - q).T)) < 0.2 * tol


def test_a_barely_observable_calibration_fits_far_past_the_limit() -> None:
    # Constant rates: the axes and the bias trade off, and the fit runs far along that null
    # space (on the finite differences' curvature): MAX_FIT_STEPS keeps it from being applied.
    gx, gy = np.meshgrid(np.linspace(30, W - 30, 9), np.linspace(30, H - 30, 7))
    ref = np.stack([gx.ravel(), gy.ravel()], axis=1)
    true = _shake_model(np.eye(3), F, (W - 1) / 2, (H - 1) / 2)
    init = _shake_model(_rot(np.array([1.0, 1.0, 0.0]), 1.0), 1.02 * F, W / 2 + 8, H / 2 - 8)
    m, p = _shake_vectors(true, ref), _shake_vectors(init, ref)
    J = np.stack([_shake_vectors(k, ref) - p for k in perturbed_models(init)], axis=2)
    _, d = session_residual(m, p, J, np.ones(len(m), bool))
    assert np.max(np.abs(d)) > 10 * MAX_FIT_STEPS


class _Voters:
    """The one field of a frame that :func:`fit_sample` reads: ``quality[2]``."""

    def __init__(self, ok: list[bool] | None) -> None:
        self.quality = None if ok is None else (None, None, np.asarray(ok, bool), None, None)


def test_the_fit_sample_spreads_over_the_sessions_voters() -> None:
    frames = [
        _Voters([True, False, True, True]),
        _Voters(None),
        _Voters([False, False]),
        _Voters([True, True, True, False, True]),
    ]
    # All the voters where the session has no more than the sample.
    pos, picks = fit_sample(frames)  # type: ignore[arg-type]
    assert pos == [0, 3]
    assert [s.tolist() for s in picks] == [[0, 2, 3], [0, 1, 2, 4]]
    # Seven voters, at most three: every third by session rank (ranks 0, 3, 6).
    pos, picks = fit_sample(frames, max_voters=3)  # type: ignore[arg-type]
    assert pos == [0, 3]
    assert [s.tolist() for s in picks] == [[0], [0, 4]]
    assert fit_sample([_Voters([False])]) == ([], [])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="max_voters"):
        fit_sample(frames, max_voters=0)  # type: ignore[arg-type]


def test_the_path_samples_resolve_a_turns_depth() -> None:
    # A dot at the centre turning at 0.78 of the exposure, between two samples (0.75 and
    # 0.8125): PATH_SAMPLES resolve its depth to 0.1 px (a fifth of source.hairpin_depth_px;
    # 0.044 px here), as 257 samples do to 0.05 px of the analytic depth.
    model = _model(0.78)
    ref = np.array([[(W - 1) / 2, (H - 1) / 2]])
    fine = float(hairpin_depth(predict_curves(model, ref, T0, EXP, 257).pts)[0])
    got = float(hairpin_depth(predict_curves(model, ref, T0, EXP, PATH_SAMPLES).pts)[0])
    assert fine == pytest.approx(_depth(0.78), abs=0.05)
    assert 0.0 < fine - got < 0.1
    assert DetectParams().source.hairpin_depth_px >= 0.5


def test_shallow_hairpins_lose_quality_ok() -> None:
    turn = 0.75  # the dot turns at 3/4 of the exposure: its end lies inside the turn
    fs, check, ok, reason, wrong = _checked(turn)
    first_ok = np.asarray(fs.quality[2], bool)
    # The image alone trusts streaks whose visible end is the turn, beyond the 2 px gate.
    assert (first_ok & wrong).sum() >= 6
    inside = ~fs.flags["clipped"]
    assert np.median(check.depth[inside]) == pytest.approx(_depth(turn), abs=0.3)
    assert not np.any(ok & wrong)
    assert set(reason[first_ok & ~ok]) == {"hairpin"}
    assert set(reason) <= set(REASONS)


def test_straight_blur_keeps_its_quality_ok() -> None:
    # Negative control: the same shake without a turn (the rate reaches zero at the end).
    fs, check, ok, _, _ = _checked(1.0)
    first_ok = np.asarray(fs.quality[2], bool)
    assert first_ok.sum() >= 10
    assert np.array_equal(ok, first_ok)
    assert np.all(check.depth < 0.1)
    assert np.nanmax(check.residual[first_ok]) < 1.0


def test_streaks_measured_along_the_curve_keep_quality_ok() -> None:
    # The gyro-template pass measured these along the predicted curve: the depth no longer
    # says their ends are unsure.
    fs, check, _, _, _ = _checked(0.75)
    fs.along_curve = np.ones(len(fs), bool)
    ok, _ = apply_check(fs, check, DetectParams().source)
    first_ok = np.asarray(fs.quality[2], bool)
    assert np.array_equal(
        ok, first_ok & ~(check.residual > DetectParams().source.gyro_vector_tol_px)
    )


@pytest.mark.parametrize("gap_px", [5.0, 6.0])
def test_the_gyro_confirms_a_lit_end_where_each_end_was_fitted_on_its_own(gap_px) -> None:
    # 35 px streaks (an edge fit at each end) with a still light just beyond two of their
    # ends, 3 to 4 PSF sigmas out (no dip for the edge fit to stop at): the image flags them
    # chained (a neighbour's light might pull the end); the gyro measures their start-to-end
    # vector right, so the ends are: confirmed, and right.
    fs, _, ok, reason, wrong = _checked(3.0, reach_px=70.0, spot_gap_px=gap_px)
    first = np.asarray(fs.quality[4], object)
    lit = (first == "chained") & fs.one_doubt
    assert lit.sum() >= 2 and not fs.short[lit].any()
    assert np.all(ok[lit]) and set(reason[lit]) == {"ok"}
    assert not np.any(ok & wrong)


@pytest.mark.parametrize("gap_px", [7.0, 8.0, 10.0])
def test_the_image_trusts_a_lit_end_past_a_dip(gap_px) -> None:
    # The same 35 px streaks, the still light 5.4 to 7.7 PSF sigmas (1.3 px) beyond two ends:
    # the profile dips between the end and the light, the edge fit stops at the dip
    # (blurtrack.detect.lines.endpoints.EDGE_LOW_SIGMAS) and the end-light window (3 to 4
    # sigmas) no longer reaches the light: the image alone trusts both streaks, and their ends
    # are within 0.5 px of the truth (before the dip rule: ``chained``, the gyro's to confirm).
    image, starts, ends = _frame(_model(3.0, 70.0), gap_px)
    p = DetectParams()
    fs = detect_frame(image, p)
    fs.quality, fs.one_doubt = frame_quality(fs, p)
    reason = np.asarray(fs.quality[4], object)
    for i in (1, 6):
        err = np.minimum(
            np.maximum(np.hypot(*(fs.end_a - starts[i]).T), np.hypot(*(fs.end_b - ends[i]).T)),
            np.maximum(np.hypot(*(fs.end_a - ends[i]).T), np.hypot(*(fs.end_b - starts[i]).T)),
        )
        k = int(np.argmin(err))
        assert err[k] < 0.5 and not fs.short[k]
        assert reason[k] == "ok" and fs.quality[2][k]
    assert not np.any(np.asarray(fs.quality[2], bool) & _wrong(fs, starts, ends))


@pytest.mark.parametrize("gap_px", [6.0, 7.0])
def test_a_short_streaks_lit_end_is_not_confirmed(gap_px) -> None:
    # Negative control: 12 px streaks, whose ends come from the moments of the whole
    # profile: the still light beyond one end pulls both ends (by over 2 px) while the
    # start-to-end vector stays right, so the gyro cannot see it: the doubt is not lifted.
    fs, check, ok, _, wrong = _checked(3.0, spot_gap_px=gap_px)
    first = np.asarray(fs.quality[4], object)
    pulled = (first == "chained") & wrong & fs.short
    assert pulled.any()
    assert np.all(check.residual[pulled] <= DetectParams().source.gyro_vector_tol_px)
    assert not np.any(fs.one_doubt[pulled]) and not np.any(ok[pulled])
    assert not np.any(ok & wrong & ~np.asarray(fs.quality[2], bool))


def test_only_streaks_with_one_doubt_and_a_fitting_vector_are_confirmed() -> None:
    fs, _, _, _, _ = _checked(1.0)
    n = len(fs)
    q = list(fs.quality)
    q[2] = np.zeros(n, bool)
    q[4] = np.full(n, "chained", object)
    fs.quality = tuple(q)
    fs.one_doubt = np.arange(n) != 3  # streak 3: two doubts
    residual = np.full(n, 0.3)
    residual[1], residual[2] = 2.5, np.nan  # off; not checked
    depth = np.zeros(n)
    depth[4] = 1.0  # the gyro says the path turns beyond an end
    ok, reason = apply_check(fs, GyroCheck(residual, depth), DetectParams().source)
    expect = np.ones(n, bool)
    expect[[1, 2, 3, 4]] = False
    assert np.array_equal(ok, expect)
    assert set(reason[~expect]) == {"chained"} and set(reason[expect]) == {"ok"}


def test_a_doubted_streak_is_confirmed_only_within_the_tighter_tolerance() -> None:
    # Between gyro_confirm_tol_px and gyro_vector_tol_px: an image-ok streak stays ok, a
    # doubted one stays refused (the vector bounds its doubted end only up to the other end's
    # own error); within both, both are ok.
    p = DetectParams().source
    assert p.gyro_confirm_tol_px < p.gyro_vector_tol_px
    fs, _, _, _, _ = _checked(1.0)
    n = len(fs)
    q = list(fs.quality)
    q[2] = np.arange(n) % 2 == 0  # even: image-ok; odd: one doubt
    q[4] = np.where(q[2], "ok", "chained").astype(object)
    fs.quality = tuple(q)
    fs.one_doubt = ~q[2]
    between = 0.5 * (p.gyro_confirm_tol_px + p.gyro_vector_tol_px)
    residual = np.where(np.arange(n) < n // 2, between, 0.5 * p.gyro_confirm_tol_px)
    ok, reason = apply_check(fs, GyroCheck(residual, np.zeros(n)), p)
    low = np.arange(n) >= n // 2
    np.testing.assert_array_equal(ok, q[2] | low)
    assert set(reason[~ok]) == {"chained"}


def _frame_off_by(delta_px: float, n: int = 40, seed: int = 4):
    """A frame's ``n`` plain streaks (true vectors 30-60 px, each end measured with a 0.25 px
    sigma per axis) against a prediction off by one vector of ``delta_px`` along x (the
    frame's model error). Returns the true vectors, the measured ones, the prediction."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0.0, 2.0 * np.pi, n)
    true = rng.uniform(30.0, 60.0, n)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    measured = true + rng.normal(0.0, 0.25, (n, 2)) - rng.normal(0.0, 0.25, (n, 2))
    return true, measured, true + np.array([delta_px, 0.0])


def test_a_right_prediction_keeps_the_session_tolerances() -> None:
    p = DetectParams().source
    true, measured, predicted = _frame_off_by(0.0)
    residual = np.hypot(*(measured - predicted).T)
    n = len(true)
    tol = frame_tolerances(residual, np.ones(n, bool), np.zeros(n), p)
    assert (tol.vector_px, tol.confirm_px) == (p.gyro_vector_tol_px, p.gyro_confirm_tol_px)
    # The ends' own noise (0.35 px a vector component here) reads as a small model error.
    assert 0.0 < tol.model_error_px < 0.3


def test_a_frame_whose_prediction_is_off_tightens_its_tolerances_by_that_error() -> None:
    """Derived truth: with the prediction off by 1.2 px, a streak whose end lies 2.3 px off
    along that error (a placement that followed the prediction) is 1.1 px from it, inside the
    session's 1.5 px and refused at the frame's; a right streak 0.3 px off passes both."""
    p = DetectParams().source
    delta = 1.2
    true, measured, predicted = _frame_off_by(delta)
    residual = np.hypot(*(measured - predicted).T)
    n = len(true)
    vector, confirm, model_px = frame_tolerances(residual, np.ones(n, bool), np.zeros(n), p)
    assert model_px == float(np.median(residual)) - p.plain_end_px
    assert model_px == pytest.approx(delta - p.plain_end_px, abs=0.25)
    assert vector == pytest.approx(p.end_gate_px - model_px)
    assert confirm == pytest.approx(vector - (p.gyro_vector_tol_px - p.gyro_confirm_tol_px))
    end_off = np.array([2.3, 0.3])  # one end off along x: wrong (> the 2 px gate), right
    r = np.abs(end_off - delta)
    assert np.all(r <= p.gyro_vector_tol_px)  # the session's tolerance passes both
    assert r[0] > vector >= r[1]  # the frame's refuses the wrong one only
    fs, _, _, _, _ = _checked(1.0)
    k = len(fs)
    q = list(fs.quality)
    q[2], q[4] = np.ones(k, bool), np.full(k, "ok", object)
    fs.quality = tuple(q)
    res = np.full(k, r[1])
    res[0] = r[0]
    tol = frame_tolerances(residual, np.ones(n, bool), np.zeros(n), p)
    ok, reason = apply_check(fs, GyroCheck(res, np.zeros(k)), p, tol)
    assert not ok[0] and reason[0] == "gyro_mismatch" and ok[1:].all()
    ok_session, _ = apply_check(fs, GyroCheck(res, np.zeros(k)), p)
    assert ok_session.all()


def test_the_model_error_comes_from_plain_streaks_not_from_hooked_placements() -> None:
    # Hooked streaks (depth above the hairpin tolerance) match a wrong prediction by
    # construction: they do not vouch for it where the frame has MIN_VOTERS plain ones.
    p = DetectParams().source
    n = MIN_VOTERS + 10
    residual = np.full(n, 1.4)  # plain: the prediction is 1.15 px off
    depth = np.zeros(n)
    depth[MIN_VOTERS:] = 3.0
    residual[MIN_VOTERS:] = 0.1  # hooked: on the prediction
    vector, _, _ = frame_tolerances(residual, np.ones(n, bool), depth, p)
    assert vector == pytest.approx(p.end_gate_px - (1.4 - p.plain_end_px))
    # Too few plain streaks: every checked ok streak gives the median.
    depth[MIN_VOTERS - 1] = 3.0
    residual[MIN_VOTERS - 1] = 0.1
    vector, _, _ = frame_tolerances(residual, np.ones(n, bool), depth, p)
    assert vector == p.gyro_vector_tol_px
    # Streaks the image refused, and unchecked ones (NaN), give nothing.
    ok = np.zeros(n, bool)
    vector, confirm, model_px = frame_tolerances(residual, ok, depth, p)
    assert (vector, confirm) == (p.gyro_vector_tol_px, p.gyro_confirm_tol_px)
    assert np.isnan(model_px)
    nan = np.full(n, np.nan)
    assert frame_tolerances(nan, np.ones(n, bool), depth, p)[0] == p.gyro_vector_tol_px


def test_frame_tolerances_never_exceed_the_session_ones_and_fall_with_the_error() -> None:
    p = DetectParams().source
    medians = np.linspace(0.0, 4.0, 41)
    got = [frame_tolerances(np.full(8, m), np.ones(8, bool), np.zeros(8), p) for m in medians]
    vec = np.array([g[0] for g in got])
    conf = np.array([g[1] for g in got])
    assert np.all(vec <= p.gyro_vector_tol_px) and np.all(conf <= p.gyro_confirm_tol_px)
    assert np.all(np.diff(vec) <= 0) and np.all(np.diff(conf) <= 0)
    assert np.all(conf <= vec)
    # Above end_gate_px + plain_end_px the frame's model vouches for nothing.
    assert np.all(vec[medians > p.end_gate_px + p.plain_end_px] < 0)
