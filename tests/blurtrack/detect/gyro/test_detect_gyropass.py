"""The gyro-template second pass (blurtrack.detect.gyro.gyropass) on an exactly rendered frame of
hairpin streaks: the shake reverses within the exposure and every dot comes back 3 px beside
its own trail, which the image-only first pass measures as one line down the middle."""

from __future__ import annotations

import dataclasses
import inspect

import cv2
import numpy as np
import pytest

from blurtrack.detect import detect_frame
from blurtrack.detect.gyro import gyroaccept, gyrocandidates, gyroconfirm, gyrogate, gyropass
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.gyropass import refine_frame
from blurtrack.detect.params import DetectParams, GyroPassParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.testing.streak_frames import line, quantise, render_streaks

W, H = 480, 360
F = 400.0
T0, EXP = 0.05, 0.04
#: Excursion (px) of the hairpin and the sideways drift that separates its arms.
REACH_PX, DRIFT_PX = 20.0, 3.0


def _rig(t: np.ndarray, omega: np.ndarray, readout_s: float = 0.0) -> BlurModel:
    """The test camera (``W x H``, focal ``F``, centred) with the gyro trace ``omega (T, 3)``
    at times ``t``, axes aligned and no time offset."""
    cam = Camera(
        resolution=(W, H), intrinsics=(F, F, (W - 1) / 2, (H - 1) / 2), readout_s=readout_s
    )
    calib = Calibration(camera=cam, R_cam_imu=np.eye(3), timeshift_cam_imu_s=0.0)
    return BlurModel(calib, GyroTrace(t, omega), gyro_upsample=1)


def _model(sign: float = 1.0, readout_s: float = 0.0) -> BlurModel:
    """A rotation about the camera's y axis that goes out and back within the exposure
    (``REACH_PX`` at mid-exposure) and a slow one about x (``DRIFT_PX`` over the exposure)."""
    t = np.arange(0.0, 0.2, 1e-3)
    wy = REACH_PX * np.pi / (F * EXP) * np.cos(np.pi * (t - T0) / EXP)
    wx = np.full_like(t, DRIFT_PX / (F * EXP))
    return _rig(t, sign * np.stack([wx, wy, 0.0 * t], axis=1), readout_s)


def _frame() -> tuple[np.ndarray, list[np.ndarray]]:
    """Twelve hairpins on a 4 x 3 grid; the truth curves from the model's point tracks
    (no rolling shutter: every row exposes over ``[T0, T0 + EXP]``)."""
    model = _model()
    dots = np.stack(np.meshgrid(70.0 + 110.0 * np.arange(4), 70.0 + 110.0 * np.arange(3)), -1)
    dots = dots.reshape(-1, 2)
    times = T0 + EXP * np.linspace(0.0, 1.0, 800)
    tracks = model.point_track(dots, np.full(len(dots), T0 + EXP / 2), times)
    curves = [tracks[i] for i in range(len(dots))]
    image = render_streaks((H, W), curves, flux_per_px=0.6, sigma_px=1.3, noise=0.004, seed=4)
    return quantise(image), curves


def _worse_end_px(fs, curves: list[np.ndarray]) -> np.ndarray:
    """Per true curve, the worse end's distance (px) of the detection nearest it (either
    order; infinite without detections)."""
    det = np.stack([fs.end_a, fs.end_b], axis=1)
    out = []
    for c in curves:
        e = np.stack([c[0], c[-1]])
        same = np.hypot(*(det - e[None]).transpose(2, 0, 1)).max(axis=1)
        swap = np.hypot(*(det - e[None, ::-1]).transpose(2, 0, 1)).max(axis=1)
        out.append(float(np.min(np.minimum(same, swap), initial=np.inf)))
    return np.array(out)


def _matched(fs, curves: list[np.ndarray], tol: float) -> int:
    """True streaks with a detection whose both ends (either order) lie within ``tol``."""
    return int(np.sum(_worse_end_px(fs, curves) < tol))


@pytest.fixture(scope="module")
def hairpins():
    image, curves = _frame()
    return image, curves, detect_frame(image)


def test_the_predicted_curves_are_hairpins_that_start_where_the_dot_starts() -> None:
    # The convention the pass relies on: samples run from the start of exposure to its end.
    model = _model()
    c = predict_curves(model, np.array([[200.0, 150.0]]), T0, EXP)
    assert c.arc[0] == pytest.approx(2 * np.hypot(REACH_PX, DRIFT_PX / 2), rel=0.05)
    assert c.chord[0] == pytest.approx(DRIFT_PX, abs=0.3)
    # A positive rotation about the camera's y axis (down) turns the optical axis towards +x,
    # so static points move towards -x: first out to -REACH_PX at mid-exposure, then back,
    # drifting towards -y (the rotation about x turns the axis towards -y... the image +y).
    mid = c.pts[0, c.pts.shape[1] // 2] - c.pts[0, 0]
    assert mid[0] == pytest.approx(-REACH_PX, abs=1.0)


def test_the_gyro_template_finds_hairpins_whole(hairpins) -> None:
    image, curves, first = hairpins
    # Negative control: the image alone measures the hairpins as single lines.
    assert _matched(first, curves, 1.0) <= 2
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), _model())
    assert what.status == "refined"
    assert _matched(out, curves, 1.0) >= len(curves) - 1
    assert len(out) == len(curves)
    # Every streak's centre line goes out and back: its arc is the hairpin's.
    assert np.all(out.length_px > 1.7 * REACH_PX)


def test_a_wrong_sign_gyro_is_refused(hairpins) -> None:
    image, _, first = hairpins
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), _model(sign=-1.0))
    assert what.status == "refused"
    assert out is first


def _pan_model(blur_px: float) -> BlurModel:
    """A steady pan about camera y that draws ``blur_px`` long streaks in one exposure."""
    t = np.arange(0.0, 0.2, 1e-3)
    omega = np.stack([0.0 * t, np.full_like(t, blur_px / (F * EXP)), 0.0 * t], axis=1)
    return _rig(t, omega)


def test_straight_streaks_are_left_to_the_first_pass() -> None:
    # A motion that does not reverse: no hairpin frame, the first pass stands untouched.
    model = _pan_model(30.0)
    dots = np.array([[100.0, 100.0], [300.0, 200.0]])
    tracks = model.point_track(dots, np.full(2, T0 + EXP / 2), T0 + EXP * np.linspace(0, 1, 400))
    image = quantise(render_streaks((H, W), list(tracks), flux_per_px=0.6, sigma_px=1.3))
    first = detect_frame(image)
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), model)
    assert what.status == "skipped" and out is first
    # The gate needs no image: a session's frames are read again only where it passes.
    read: list[int] = []

    def reader(img: np.ndarray):
        def read_it() -> np.ndarray:
            read.append(1)
            return img

        return read_it

    assert refine_frame(reader(image), first, FrameTiming(T0, EXP), model)[0] is first
    assert not read
    hp_image, _ = _frame()
    refine_frame(reader(hp_image), detect_frame(hp_image), FrameTiming(T0, EXP), _model())
    assert read == [1]


def _hairpin_gyro(fps: float, reach_px: float, drift_px: float, f_px: float):
    """A ``shake`` stand-in: about y, one period per frame (out and back within an exposure
    of half a period, the frames starting on whole periods); about x, a slow drift."""
    period = 1.0 / fps

    def omega(t_s: np.ndarray, seed: int, amplitude_radps: float) -> np.ndarray:
        a = reach_px / f_px * 2 * np.pi / period
        wy = a * np.cos(2 * np.pi * t_s / period)
        wx = np.full_like(t_s, drift_px / f_px / (period / 2))
        return np.stack([wx, wy, 0.0 * t_s], axis=1)

    return omega


def test_the_session_runs_the_pass(tmp_path, monkeypatch) -> None:
    # Every frame of this session is a hairpin frame, which fools the time-shift scan (it
    # compares the first pass's lines with the predicted ends): the session's guess (the
    # truth here) is used as it is.
    from blurtrack.detect import DetectParams
    from blurtrack.detect.session.pipeline import detect_session
    from blurtrack.io.session import load_session
    from blurtrack.testing import mini_session

    fps, w = 25.0, 320
    monkeypatch.setattr(mini_session, "shake", _hairpin_gyro(fps, 14.0, 3.0, 0.9 * w))
    truth = mini_session.write_synthetic_session(
        tmp_path / "s", n_frames=3, seed=5, fps=fps, exposure_s=0.5 / fps, sigma_px=1.3
    )
    session = load_session(tmp_path / "s")
    on = detect_session(session, gyro="on", refine_timeshift=False)
    off = detect_session(
        session, DetectParams(gyro_template=False), gyro="on", refine_timeshift=False
    )
    assert on.summary["gyro_template_frames"] == {"refined": 3}
    assert off.summary["gyro_template_frames"] == {}
    comps = on.summary["gyro_template_components"]
    assert 0 < comps["replaced"] <= comps["candidates"]
    assert comps["streaks"] >= comps["replaced"]  # each replaced component holds a streak
    assert off.summary["gyro_template_components"] == {"candidates": 0, "replaced": 0, "streaks": 0}
    for res, least, most in ((on, 0.9, 1.0), (off, 0.0, 0.2)):
        hit = n = 0
        for fr in truth["frames"]:
            d = res.table[res.table.frame == fr["index"]]
            s = d[["start_x", "start_y"]].to_numpy()
            e = d[["end_x", "end_y"]].to_numpy()
            for st in fr["streaks"]:
                if not st["inside"]:
                    continue
                n += 1
                err = np.maximum(
                    np.hypot(*(s - st["start"]).T), np.hypot(*(e - st["end"]).T)
                )  # oriented: start and end as the session resolved them
                hit += int(err.min() < 1.0)
        assert least * n <= hit <= most * n


def test_a_measured_line_of_the_placed_shape_is_confirmed_a_little_along_the_chain() -> None:
    # A straight placed curve of 100 px; tolerance 12.5 px (tol_px + tol_rel * arc).
    gp = GyroPassParams()
    s, e = np.array([[100.0, 50.0]]), np.array([[200.0, 50.0]])
    tol = np.array([gp.tol_px + gp.tol_rel * 100.0])
    along = np.array([1.5 * tol[0], 0.0])
    k = gp.shape_shift_factor
    # The same line: confirmed, in either orientation.
    assert gyroconfirm.confirmed(s, e, s, e, tol, k)[0]
    assert gyroconfirm.confirmed(e, s, s, e, tol, k)[0]
    # The dot's line 1.5 tolerances along the chain from its placement: the position alone
    # (negative control) refuses it, the shape confirms it.
    assert gyroconfirm.mismatch(s + along, e + along, s, e)[0] > tol[0]
    assert gyroconfirm.confirmed(s + along, e + along, s, e, tol, k)[0]
    # Too far along (over shape_shift_factor tolerances), or of another shape (a fragment of
    # 60 px, a line turned by 20 degrees) that far off: refused.
    far = np.array([(k + 0.1) * tol[0], 0.0])
    assert not gyroconfirm.confirmed(s + far, e + far, s, e, tol, k)[0]
    assert not gyroconfirm.confirmed(s + along, s + along + [60.0, 0.0], s, e, tol, k)[0]
    turned = s + along + 100.0 * np.array([np.cos(0.35), np.sin(0.35)])
    assert not gyroconfirm.confirmed(s + along, turned, s, e, tol, k)[0]


def test_components_at_the_border_are_candidates() -> None:
    # Three hairpins whose turn a short streak entering from the left border joins (their
    # components touch the border) and three inside.
    model = _model()
    dots = np.array([[12.0, 70.0], [12.0, 180.0], [12.0, 290.0], [180.0, 70.0], [180.0, 180.0]])
    dots = np.concatenate([dots, [[290.0, 290.0]]])
    times = T0 + EXP * np.linspace(0.0, 1.0, 800)
    tracks = model.point_track(dots, np.full(len(dots), T0 + EXP / 2), times)
    curves = [tracks[i] for i in range(len(dots))]
    stubs = [
        np.stack([np.linspace(-6.0, 6.0, 50), np.full(50, y + 1.5)], 1)
        for y in (70.0, 180.0, 290.0)
    ]
    image = quantise(
        render_streaks((H, W), curves + stubs, flux_per_px=0.6, sigma_px=1.3, noise=0.004, seed=4)
    )
    first = detect_frame(image)
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), model)
    assert what.status == "refined" and what.candidates == 6
    assert _matched(out, curves[3:], 1.0) == 3
    assert len(out) == len(first)  # the border components keep their lines, none is lost
    # Negative control: without border candidates only the three inside are.
    inside_only = DetectParams(gyro_pass=GyroPassParams(border_candidates=False))
    out2, what2 = refine_frame(image, first, FrameTiming(T0, EXP), model, inside_only)
    assert what2.candidates == 3
    assert _matched(out2, curves[3:], 1.0) == 3


def test_a_placed_curve_is_cut_at_the_frame_border() -> None:
    # A straight curve from x = -25 to x = 75 on row 50 (samples 10 px apart): its part inside
    # the frame starts where it crosses x = 0, not at its first sample inside (x = 5).
    curve = np.stack([np.linspace(-25.0, 75.0, 11), np.full(11, 50.0)], 1)
    s, e = gyroconfirm.cut_at_border(curve, W, H)
    assert s == pytest.approx([0.0, 50.0]) and e == pytest.approx([75.0, 50.0])
    # Diagonally out through the bottom-right corner's bottom edge (y = H - 1).
    diag = np.stack([np.linspace(400.0, 500.0, 11), np.linspace(300.0, 400.0, 11)], 1)
    s, e = gyroconfirm.cut_at_border(diag, W, H)
    assert s == pytest.approx([400.0, 300.0]) and e == pytest.approx([459.0, H - 1.0])
    # Wholly inside: its own ends.
    inner = curve + np.array([40.0, 0.0])
    s, e = gyroconfirm.cut_at_border(inner, W, H)
    assert s == pytest.approx(inner[0]) and e == pytest.approx(inner[-1])


def test_a_chain_into_the_border_is_split_by_curves_cut_at_the_border(monkeypatch) -> None:
    # Straight streaks (~85 px) on a 55 px grid along the motion: three rows of three dots
    # form chains whose first streak leaves the frame at the left border; one chain of two
    # and three isolated streaks lie inside. No template wholly inside the frame explains a
    # border chain's light, so without placements past the border (negative control) the
    # chains stay; with them every inside streak is found.
    model = _pan_model(70.0)
    sp = 55.0
    dots = [[x, y] for y in (60.0, 150.0, 240.0) for x in (10.0, 10.0 + sp, 10.0 + 2 * sp)]
    dots += [[420.0, 60.0], [420.0, 150.0], [420.0, 240.0], [250.0, 320.0], [250.0 + sp, 320.0]]
    times = T0 + EXP * np.linspace(0.0, 1.0, 800)
    tracks = model.point_track(np.array(dots), np.full(len(dots), T0 + EXP / 2), times)
    curves = list(tracks)
    image = quantise(
        render_streaks((H, W), curves, flux_per_px=0.6, sigma_px=1.3, noise=0.004, seed=4)
    )
    inside = [c for c in curves if c[:, 0].min() > 3.0]
    chained = [inside[i] for i in range(6)]  # the border chains' inside streaks
    assert len(inside) == 11
    first = detect_frame(image)
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), model)
    assert what.status == "refined"
    assert _matched(out, inside, 3.0) == len(inside)
    # The streaks leaving the frame are there too, flagged clipped, ending at the border.
    clipped = out.flags["clipped"]
    assert int(clipped.sum()) == 3
    assert np.all(np.minimum(out.end_a[clipped, 0], out.end_b[clipped, 0]) < 1.0)
    assert len(out) == len(curves)
    # Negative controls: placed curves not cut at the border (their ends outside the frame,
    # 20-30 px from the measured ones) refuse the border chains' placements; no placements
    # past the border leave the chains.
    with monkeypatch.context() as mp:
        mp.setattr(gyroaccept, "cut_at_border", lambda c, w, h: (c[0], c[-1]))
        out1, _ = refine_frame(image, first, FrameTiming(T0, EXP), model)
        assert _matched(out1, chained, 3.0) <= 1
    no_clip = DetectParams(gyro_pass=GyroPassParams(clip_at_border=False))
    out2, _ = refine_frame(image, first, FrameTiming(T0, EXP), model, no_clip)
    assert _matched(out2, chained, 3.0) <= 1


def test_a_frame_of_chains_is_accepted_a_wrong_prior_is_not(hairpins) -> None:
    # The measured margins (hard seed 3 frame 6: 66 of 160 placements confirmed in
    # components replaced whole; the rendered hairpins under the reversed gyro: 3 of 11).
    accept_min = GyroPassParams().accept_min
    assert gyroconfirm.accepted(66, 160, accept_min)
    assert not gyroconfirm.accepted(3, 11, accept_min)
    assert not gyroconfirm.accepted(66, 160, 0.5)  # negative control: the former threshold
    image, _, first = hairpins
    assert refine_frame(image, first, FrameTiming(T0, EXP), _model(sign=-1.0))[1].status == (
        "refused"
    )


def test_the_norm_inside_the_frame_is_the_mask_correlation() -> None:
    # A padded image of 40 x 30 px around a 20 x 12 px frame: the template's squared norm
    # inside the frame per placement equals the correlation of the frame's mask with the
    # template's square; None where every placement lies inside.
    from blurtrack.detect.separation.templates import inside_norm2

    rng = np.random.default_rng(3)
    sm = rng.random((7, 9)).astype(np.float32)
    frame = (10, 8, 30, 20)
    mask = np.zeros((30, 40), np.float32)
    mask[8:20, 10:30] = 1.0
    region = (2, 3, 36, 27)
    got = inside_norm2(frame, region, sm)
    want = cv2.matchTemplate(mask[3:27, 2:36], sm * sm, cv2.TM_CCORR)
    assert got is not None and got.shape == want.shape
    assert np.allclose(got, want, rtol=1e-5, atol=1e-5)
    assert inside_norm2(frame, (10, 8, 30, 20), sm) is None
    assert inside_norm2(None, region, sm) is None


def test_the_gates_coarse_curves_have_the_full_curves_ends_and_middle() -> None:
    # With a rolling shutter, so that each sample's row time is iterated: the gate decides on
    # the ends, the midpoint and the arc of GATE_SAMPLES-point curves.
    model = _model(readout_s=0.02)
    dots = np.array([[40.0, 30.0], [200.0, 150.0], [390.0, 270.0]])
    full = predict_curves(model, dots, T0, EXP)
    gate = predict_curves(model, dots, T0, EXP, gyrogate.GATE_SAMPLES)
    S, G = full.pts.shape[1], gate.pts.shape[1]
    assert G == gyrogate.GATE_SAMPLES < S and G % 2 == 1
    # the same instants: integrated along 17 or 65 samples, they agree to a few thousandths
    # of a px (the gate's tolerance is 2.5 px; a sample half a step off would move ~1 px)
    np.testing.assert_allclose(
        gate.pts[:, [0, G // 2, -1]], full.pts[:, [0, S // 2, -1]], rtol=0, atol=0.005
    )
    # the arc of fewer points is shorter, by far less than the gate's tolerance (0.1 of it)
    assert np.all(gate.arc <= full.arc) and np.all(full.arc - gate.arc < 0.01 * full.arc)
    # negative control: an even count has no mid-exposure sample
    even = predict_curves(model, dots, T0, EXP, 16)
    assert not np.allclose(even.pts[:, 8], full.pts[:, S // 2])


def test_one_dots_light_is_a_components_light_per_line_not_a_chains() -> None:
    # Hard seed 2 frame 8's make-up: most components inside the frame are chains of two to
    # six long streaks that the first pass split into as many lines, a few hold one dot
    # (155 units each); components at the border do not count.
    rng = np.random.default_rng(3)
    n_lines = np.array([1] * 6 + [2] * 8 + [3] * 5 + [6] * 3 + [1, 1])
    light = 155.0 * n_lines * rng.uniform(0.97, 1.03, n_lines.size)
    border = np.zeros(n_lines.size, bool)
    border[-2:] = True
    light[-2:] = 40.0  # streaks leaving the frame: part of a dot
    quantile = GyroPassParams().light_quantile
    est = gyrocandidates.one_dot_light(light, border, n_lines, quantile)
    assert abs(est - 155.0) < 5.0
    # Negative control: the former estimate (the 0.4 quantile of the components' light) is
    # two dots', at which the pursuit sees every dot at amplitude 0.5, under amp_min.
    former = float(np.quantile(light[~border], quantile))
    assert former > 1.8 * 155.0
    assert 155.0 / former < DetectParams().separation.amp_min
    # Without any first-pass line inside the frame the quantile stands.
    none = np.zeros_like(n_lines)
    assert gyrocandidates.one_dot_light(light, border, none, quantile) == former


def test_blown_out_hairpins_are_point_lights_not_touching() -> None:
    # The twelve hairpins blown out (peak ~3.7x white): each arm's clipped core runs into the
    # other arm's, 3 px away, so neither arm has a cross-section of its own. The pass
    # measures no width for them (NaN), nor calls them merged; the lit area says point.
    model = _model()
    _, curves = _frame()
    bright = quantise(render_streaks((H, W), curves, 12.0, 1.3, noise=0.004, seed=4))
    assert np.mean(bright == 255) > 0.005
    out, what = refine_frame(bright, detect_frame(bright), FrameTiming(T0, EXP), model)
    assert what.status == "refined" and out.evidence is not None
    assert _matched(out, curves, 1.5) == len(curves) == len(out)
    assert out.flags["saturated"].all() and np.isnan(out.width_px).all()
    assert not out.flags["merged"].any()
    assert list(out.evidence.source) == ["point"] * len(curves)
    # Negative control: unsaturated, the arms' widths are measured (a single dot's).
    image, _ = _frame()
    dim, _ = refine_frame(image, detect_frame(image), FrameTiming(T0, EXP), model)
    assert np.all(np.abs(dim.width_px / dim.sigma_c_px - 1.0) < 0.15)


def test_the_pass_holds_widths_to_the_sigma_it_measured_with(hairpins) -> None:
    # A frame whose own sigma came out narrow (its unsaturated lines faint fragments, whose
    # cores alone rise over the noise: hard seed 17 frame 4, 1.03 px against 1.87 in the
    # other frames): the pass measures with the session's sigma and holds the widths to it,
    # so its dots of the optics' width are neither merged nor of undetermined source.
    image, curves, first = hairpins
    narrow = dataclasses.replace(first, sigma_c_px=0.55 * first.sigma_c_px)
    out, what = refine_frame(
        image, narrow, FrameTiming(T0, EXP), _model(), sigma_c=first.sigma_c_px
    )
    assert what.status == "refined" and out.evidence is not None
    assert _matched(out, curves, 1.0) >= len(curves) - 1
    assert not out.flags["merged"].any()
    assert list(out.evidence.source) == ["point"] * len(out)
    # Negative control: against the frame's own sigma every one of them is wider than a dot.
    limit = DetectParams().quality.merged_width * narrow.sigma_c_px
    assert np.all(out.width_px > limit)


def test_kept_first_pass_lines_stay_held_to_the_frames_sigma() -> None:
    # Two straight lines beside the hairpins: no hairpin template fits them, so the refined
    # frame keeps their first-pass lines. Those were measured (and flagged) against the
    # frame's own sigma and stay judged against it; the pass's streaks against the sigma the
    # pass measured with. (Against the session's sigma the two lines would be point lights.)
    _, curves = _frame()
    extra = [line((395.0, 330.0), (445.0, 335.0)), line((20.0, 20.0), (20.0, 60.0))]
    image = quantise(render_streaks((H, W), curves + extra, 0.6, 1.3, noise=0.004, seed=4))
    first = detect_frame(image)
    narrow = dataclasses.replace(first, sigma_c_px=0.55 * first.sigma_c_px)
    timing = FrameTiming(T0, EXP)
    out, what = refine_frame(image, narrow, timing, _model(), sigma_c=first.sigma_c_px)
    assert what.status == "refined" and out.evidence is not None
    kept, new = ~out.along_curve, out.along_curve
    assert kept.sum() == 2 and new.sum() == len(curves)
    ratio = out.evidence.width_ratio
    np.testing.assert_allclose(ratio[kept], out.width_px[kept] / narrow.sigma_c_px)
    np.testing.assert_allclose(ratio[new], out.width_px[new] / first.sigma_c_px)
    assert list(out.evidence.source[kept]) == ["undetermined"] * 2
    assert np.all(np.abs(out.width_px[kept] / first.sigma_c_px - 1.0) < 0.1)


def _hook_model(length_px: float, hook_px: float, ramp: float) -> BlurModel:
    """A pan about camera y drawing ``length_px`` along -x that, over the last ``ramp`` of
    the exposure, slows to a stop while a rotation about x turns the path ``hook_px`` along
    y: every dot's streak ends in a hook, its slow end the brightest part."""
    t = np.arange(0.0, 0.2, 1e-4)
    s = np.clip((t - (T0 + (1.0 - ramp) * EXP)) / (ramp * EXP), 0.0, 1.0)
    wy = length_px / (F * EXP * (1.0 - ramp / 2)) * (1.0 - s)
    wx = hook_px / (F * EXP * ramp / 2) * s
    return _rig(t, np.stack([wx, wy, 0.0 * t], axis=1))


def test_a_line_near_its_prediction_is_measured_again_where_its_end_hooks(monkeypatch) -> None:
    # Saturated streaks whose paths hook by 3 px as the dot slows to its exposure-end stop:
    # the first pass draws each line straight into the blown-out end. Two dots whose streaks
    # touch make a chain that misses its prediction, so the gate lets the frame through.
    model = _hook_model(40.0, 3.0, 0.4)
    dots = np.stack(np.meshgrid(90.0 + 100.0 * np.arange(4), 60.0 + 90.0 * np.arange(3)), -1)
    dots = dots.reshape(-1, 2)
    dots = np.vstack([dots, dots[5] + [20.0, 0.0]])
    tracks = model.point_track(
        dots, np.full(len(dots), T0 + EXP / 2), T0 + EXP * np.linspace(0.0, 1.0, 1200)
    )
    image = quantise(
        render_streaks((H, W), list(tracks), flux_per_px=6.0, sigma_px=1.3, noise=0.004, seed=4)
    )
    assert np.mean(image >= 255) > 0.005  # the slow ends are blown out
    single = [i for i in range(len(dots)) if i not in (5, len(dots) - 1)]
    curves = [tracks[i] for i in single]
    first = detect_frame(image)
    before = _worse_end_px(first, curves)
    # Negative control: every first-pass line lies within the tolerance of its prediction
    # (no mismatch singles it out), yet its hooked end is off.
    assert np.all(before < GyroPassParams().tol_px)
    assert np.all(before > 0.6) and np.sum(before > 1.2) >= 2
    limits: list[int | None] = []
    real = gyropass.pursue

    def spy(*args, **kwargs):
        limits.append(inspect.signature(real).bind(*args, **kwargs).arguments.get("limit"))
        return real(*args, **kwargs)

    monkeypatch.setattr(gyropass, "pursue", spy)
    out, what = refine_frame(image, first, FrameTiming(T0, EXP), model)
    assert what.status == "refined"
    # Each single line's component was pursued once, for one placement (one dot; no sweep:
    # a second placement would slide along the line, which
    # test_a_chain_into_the_border_is_split_by_curves_cut_at_the_border would count).
    assert limits.count(1) == len(single)
    after = _worse_end_px(out, curves)
    assert np.all(after < 0.5)


class _PathMotion:
    """A stand-in blur model: every point follows the polyline ``corners`` (px, relative)
    at constant speed over the exposure ``[T0, T0 + EXP]`` (no readout)."""

    def __init__(self, corners: list[list[float]]) -> None:
        c = np.asarray(corners, float)
        seg = np.hypot(*np.diff(c, axis=0).T)
        self.at = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
        self.c = c
        self.camera = type(
            "Cam", (), {"readout_s": 0.0, "height": H, "intrinsics": None, "dist": None}
        )()

    def _offset(self, t: np.ndarray) -> np.ndarray:
        s = np.clip((np.asarray(t, float) - T0) / EXP, 0.0, 1.0)
        return np.stack(
            [np.interp(s, self.at, self.c[:, 0]), np.interp(s, self.at, self.c[:, 1])], -1
        )

    def point_track_ordered(
        self, pixels: np.ndarray, t_ref: np.ndarray, times: np.ndarray
    ) -> np.ndarray:
        return pixels[:, None, :] + self._offset(times) - self._offset(t_ref)[:, None, :]

    def orientation_grid(self, _lo: np.ndarray, _hi: np.ndarray, _step: float) -> _PathMotion:
        return self  # the path is the grid: tracks of any length read from it

    def point_track(
        self, pixels: np.ndarray, t_ref: np.ndarray, times: np.ndarray, *_: object
    ) -> np.ndarray:
        return self.point_track_ordered(pixels, t_ref, times)

    def directions(
        self, pixels: np.ndarray, t_ref: np.ndarray, *_: object
    ) -> tuple[np.ndarray, np.ndarray, None]:
        # (the grid's directions: here the points and their times)
        return np.asarray(pixels, float).reshape(-1, 2), np.asarray(t_ref, float), None

    def track_directions(
        self, seen: tuple[np.ndarray, np.ndarray, None], times: np.ndarray, *_: object
    ) -> np.ndarray:
        return self.point_track_ordered(seen[0], seen[1], times)


def test_the_gate_lets_through_a_frame_whose_streaks_hook() -> None:
    """Streaks whose first-pass ends sit exactly on their predicted ends (nothing to refine by
    the mismatch test), on a path that starts with a 3 px hook sideways (chord 0.81 of the arc:
    not a hairpin frame): the gate lets the frame through for its hooks (the check's depth on
    the gate's 17 samples, 3.4 px, over 0.5 px) and not without the depth tolerance; a
    straight path is let through neither way (negative control)."""
    mids = np.array([[100.0, 100.0], [200.0, 150.0], [300.0, 200.0]])
    timing = FrameTiming(T0, EXP)
    gp = GyroPassParams()
    for corners, hooked in (
        ([[0, 3], [0, 0], [-2, 0], [30, 0]], True),
        ([[0, 0], [37, 0]], False),
    ):
        model = _PathMotion(corners)
        curves = predict_curves(model, mids, T0, EXP, gyrogate.GATE_SAMPLES)
        mid = curves.pts.shape[1] // 2
        placed = curves.pts - curves.pts[:, mid, None] + mids[:, None]
        fs = type(
            "FS",
            (),
            {
                "flags": {"clipped": np.zeros(3, bool)},
                "time_mid": mids,
                "end_a": placed[:, 0],
                "end_b": placed[:, -1],
                "__len__": lambda s: 3,
            },
        )()
        assert gyrogate.gate(fs, timing, model, gp) is None
        got = gyrogate.gate(fs, timing, model, gp, hook_depth_px=0.5)
        assert got == ("hooks" if hooked else None), corners


def test_the_gate_lets_through_a_frame_whose_vectors_miss_the_corrected_prediction() -> None:
    """Straight 6 px streaks, within the mismatch tolerance of their prediction (2.5 px), but
    measured 1.6 px too long (a first-pass density fit of a dot that slows at both ends): with
    the session-corrected model the gate lets the frame through for its vectors; without a
    corrected model (no tolerance) it does not, nor where the lines are right (negative
    control)."""
    mids = np.array([[100.0, 100.0], [200.0, 150.0], [300.0, 200.0], [400.0, 250.0]])
    timing = FrameTiming(T0, EXP)
    gp = GyroPassParams()
    model = _PathMotion([[0, 0], [6, 0]])
    curves = predict_curves(model, mids, T0, EXP, gyrogate.GATE_SAMPLES)
    for stretch, expected in ((0.8, "vectors"), (0.0, None)):
        a = mids - np.array([3.0 + stretch, 0.0])
        b = mids + np.array([3.0 + stretch, 0.0])
        fs = type(
            "FS",
            (),
            {
                "flags": {"clipped": np.zeros(4, bool)},
                "time_mid": mids,
                "end_a": a,
                "end_b": b,
                "__len__": lambda s: 4,
            },
        )()
        assert gyrogate.gate(fs, timing, model, gp, hook_depth_px=0.5) is None
        got = gyrogate.gate(fs, timing, model, gp, hook_depth_px=0.5, vector_tol_px=1.5)
        assert got == expected, stretch
        # Without the time law the pass would measure them as the first pass did.
        no_law = dataclasses.replace(gp, time_law=False)
        assert (
            gyrogate.gate(fs, timing, model, no_law, hook_depth_px=0.5, vector_tol_px=1.5) is None
        )
    res = gyrogate.vector_residual(a, b, curves.pts)
    np.testing.assert_allclose(res, 0.0, atol=1e-9)
    # Orientation-free: a reversed line is the same vector.
    np.testing.assert_allclose(gyrogate.vector_residual(b, a, curves.pts), 0.0, atol=1e-9)


def test_a_short_return_is_a_hook_measured_as_one_line_a_long_one_has_arms() -> None:
    """A 6 px curve that runs 0.7 px past its end and back is one line under its law; with
    a 3 px return, or on a curve long enough for edge fits, or without the law, two arms."""
    from blurtrack.detect.gyro.gyromeasure import _arms

    def curve(out_px: float, back_px: float) -> np.ndarray:
        x = np.concatenate(
            [np.linspace(0, out_px, 50), np.linspace(out_px, out_px - back_px, 16)[1:]]
        )
        return np.stack([x, np.zeros_like(x)], axis=1)

    gp = GyroPassParams()
    sigma = 1.3
    for out_px, back_px, arms in ((6.7, 0.7, False), (8.0, 3.0, True), (30.0, 0.7, True)):
        pts = curve(out_px, back_px)
        arc = float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))
        assert _arms(pts, 49, arc, sigma, gp) is arms, (out_px, back_px)
    pts = curve(6.7, 0.7)
    arc = float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))
    assert _arms(pts, 49, arc, sigma, dataclasses.replace(gp, time_law=False)) is True
