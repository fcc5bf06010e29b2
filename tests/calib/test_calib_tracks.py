"""Inter-frame tracks (calib.tracks): pairing, the pseudo-streak residual, and fits that a
detector's length bias does not move."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GYRO_UPSAMPLE
from calib.data import StreakSet, relative_gyro
from calib.errors import CalibError
from calib.fit import FitOptions, calibrate
from calib.grid import GridEvaluator
from calib.params import theta_from
from calib.problem import ResidualModel, choose_substeps
from calib.testing import make_problem
from calib.tracks import build_tracks, concat, mean_rows


def _model(p, streaks: StreakSet) -> ResidualModel:
    g = relative_gyro(p.gyro.upsampled(GYRO_UPSAMPLE), streaks.t0_s)
    cam = p.truth.camera
    return ResidualModel(
        g, p.truth.R_cam_imu, cam.dist, cam.height, choose_substeps(streaks, cam.height, 0.05)
    )


@pytest.fixture(scope="module")
def exact():
    return make_problem(seed=5, n_frames=12, dots_per_frame=30, endpoint_noise_px=0.0, tracked=True)


def test_tracks_pair_the_same_dot_and_vanish_at_the_truth(exact) -> None:
    p = exact
    model = _model(p, p.streaks)
    tracks, pairs = build_tracks(model, theta_from(p.truth), p.streaks)
    ids = p.streaks.streak_id
    frames = p.streaks.frame
    assert len(tracks) > 0.8 * len(p.streaks) * 11 / 12  # most dots stay in view
    assert np.all(ids[pairs[:, 0]] == ids[pairs[:, 1]])
    assert np.all(frames[pairs[:, 1]] == frames[pairs[:, 0]] + 1)
    # Every dot seen in two consecutive frames is paired exactly once.
    expected = sum(np.intersect1d(ids[frames == f], ids[frames == f + 1]).size for f in range(11))
    assert len(tracks) == expected
    # A track spans mid-exposure to mid-exposure of the next frame, dated by its mean rows.
    assert np.allclose(tracks.exposure_s, 0.05)
    assert np.allclose(tracks.rows[:, 1], mean_rows(p.streaks)[pairs[:, 1]])
    big = _model(p, concat([p.streaks, tracks]))
    r = big.residual_np(theta_from(p.truth), tracks)
    # The truth's dense gyro against the measured 200 Hz samples: well under 0.01 px.
    assert np.max(np.linalg.norm(r, axis=1)) < 5e-3


def test_track_jacobian_matches_numpy_and_finite_differences(exact) -> None:
    p = exact
    tracks, _ = build_tracks(_model(p, p.streaks), theta_from(p.truth), p.streaks)
    sub = tracks.subset(np.arange(0, len(tracks), 7))
    model = _model(p, concat([p.streaks, tracks]))
    th = theta_from(p.initial).astype(float)
    cam = p.truth.camera
    ev = GridEvaluator(model.gyro, model.R0_cam_imu, cam.dist, cam.height)
    r, J = ev.evaluate(th, sub)
    assert np.allclose(r, ev.residual(th, sub), atol=1e-9)
    assert np.max(np.abs(r - model.residual_np(th, sub))) < 3e-3  # the per-streak model
    # Time derivatives take ω at the ends of the (frame-period) interval: exact to the
    # grid's quadrature.
    for i, h in ((0, 1e-7), (1, 1e-3), (4, 1e-3), (5, 1e-7), (7, 1e-6)):
        tp, tm = th.copy(), th.copy()
        tp[i] += h
        tm[i] -= h
        fd = (ev.residual(tp, sub) - ev.residual(tm, sub)) / (2 * h)
        tol = 3e-3 if i in (0, 5) else 3e-4
        assert np.max(np.abs(fd - J[:, :, i])) <= tol * np.max(np.abs(fd)), i


def test_track_fit_is_unmoved_by_a_length_bias() -> None:
    # Both ends 0.15 px outwards on every streak, as a detector might: the endpoint fit takes it
    # for a longer focal length, the track fit (midpoints only) does not see it.
    p = make_problem(
        seed=2,
        n_frames=30,
        dots_per_frame=40,
        endpoint_noise_px=0.05,
        tracked=True,
        end_bias_px=0.15,
        shift_error_s=0.02,
        focal_error=0.04,
    )
    truth = theta_from(p.truth)
    ep = calibrate(p.streaks, p.gyro, p.initial, FitOptions(residuals="endpoints"))
    tr = calibrate(p.streaks, p.gyro, p.initial, FitOptions(residuals="tracks"))
    assert tr.converged and tr.status in ("ok", "warning"), tr.warnings
    assert tr.residuals == "tracks" and tr.n_tracks > 500 and tr.tracks is not None
    err_ep = abs(ep.values["fx"] / truth[1] - 1)
    err_tr = abs(tr.values["fx"] / truth[1] - 1)
    assert err_ep > 3e-3  # the bias, seen as focal length (2.5 sigma there)
    assert err_tr < 1.5e-3 and err_tr < err_ep / 3
    for k, name in enumerate(("timeshift_s", "fx", "fy", "cx", "cy", "readout_s")):
        assert abs(tr.values[name] - truth[k]) < 4 * tr.sigma[name], name
    both = calibrate(p.streaks, p.gyro, p.initial, FitOptions(residuals="both"))
    assert both.converged and both.n_tracks == tr.n_tracks
    assert both.to_dict()["residuals"] == "both"


def test_tracks_need_midpoints_and_consecutive_frames(exact) -> None:
    p = exact
    no_mid = StreakSet(
        p.streaks.start,
        p.streaks.end,
        p.streaks.frame_t_s,
        p.streaks.exposure_s,
        p.streaks.frame,
        p.streaks.streak_id,
        p.streaks.t0_s,
    )
    with pytest.raises(CalibError, match="midpoints"):
        calibrate(no_mid, p.gyro, p.initial, FitOptions(residuals="tracks"))
    sparse = p.streaks.subset(p.streaks.frame % 3 == 0)  # no two frames within reach
    tracks, pairs = build_tracks(_model(p, sparse), theta_from(p.truth), sparse)
    assert len(tracks) == 0 and pairs.shape == (0, 2)
    with pytest.raises(CalibError, match="inter-frame tracks"):
        calibrate(sparse, p.gyro, p.initial, FitOptions(residuals="tracks", holdout_fraction=0))


def test_options_and_time_rows_are_validated() -> None:
    with pytest.raises(CalibError, match="residuals"):
        FitOptions(residuals="midpoints")
    with pytest.raises(CalibError, match="endpoint residuals only"):
        FitOptions(residuals="tracks", frame_noise=True)
    z = np.zeros((2, 2))
    with pytest.raises(CalibError, match="time rows"):
        StreakSet(
            z, z + 1, np.zeros(2), np.ones(2), np.arange(2), np.arange(2), time_row=np.zeros((3, 2))
        )
    with pytest.raises(CalibError, match="midpoints"):
        StreakSet(
            z,
            z + 1,
            np.zeros(2),
            np.ones(2),
            np.arange(2),
            np.arange(2),
            mid=np.full((2, 2), np.nan),
        )
    s = StreakSet(
        z,
        z + 1,
        np.zeros(2),
        np.ones(2),
        np.arange(2),
        np.arange(2),
        time_row=np.array([[1.0, 2.0], [3.0, 4.0]]),
    )
    assert s.reoriented(np.array([True, False])).rows.tolist() == [[2.0, 1.0], [3.0, 4.0]]
    assert s.flipped().rows.tolist() == [[2.0, 1.0], [4.0, 3.0]]
    assert StreakSet(
        z, z + 1, np.zeros(2), np.ones(2), np.arange(2), np.arange(2)
    ).rows.tolist() == [[0.0, 1.0], [0.0, 1.0]]


def test_auto_picks_tracks_or_endpoints() -> None:
    p = make_problem(
        seed=4,
        n_frames=14,
        dots_per_frame=30,
        endpoint_noise_px=0.05,
        tracked=True,
        shift_error_s=0.01,
        focal_error=0.02,
    )
    res = calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0))
    assert res.residuals == "tracks" and res.n_tracks > 300
    # Midpoints of most streaks moved far off: few tracks are left, fitted alone, with a
    # warning.
    rng = np.random.default_rng(0)
    ang = rng.uniform(0, 2 * np.pi, len(p.streaks))
    off = np.stack([np.cos(ang), np.sin(ang)], axis=1) * 40.0
    mid = p.streaks.mid + np.where(rng.random(len(p.streaks)) < 0.6, 1.0, 0.0)[:, None] * off
    from dataclasses import replace

    few = calibrate(replace(p.streaks, mid=mid), p.gyro, p.initial, FitOptions(holdout_fraction=0))
    assert few.residuals == "tracks" and 30 <= few.n_tracks < 0.25 * len(p.streaks)
    assert any("the fit uses the tracks only" in w for w in few.warnings)
    bare = calibrate(
        replace(p.streaks, mid=None), p.gyro, p.initial, FitOptions(holdout_fraction=0)
    )
    assert bare.residuals == "endpoints" and bare.tracks is None
    assert any("no time midpoints" in w for w in bare.warnings)
