"""Known-value calibration on synthetic streaks from the core model, and bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from calib.data import StreakSet
from calib.errors import CalibError
from calib.fit import FitOptions, calibrate
from calib.params import rotation_error_rad, theta_from
from calib.testing import make_problem


@pytest.fixture(scope="module")
def fitted():
    p = make_problem(
        seed=11,
        n_frames=24,
        dots_per_frame=40,
        endpoint_noise_px=0.1,
        shift_error_s=-0.045,
        focal_error=0.09,
    )
    return p, calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.25))


def test_recovers_truth_from_far_guess(fitted) -> None:
    p, res = fitted
    assert res.status in ("ok", "warning"), res.warnings
    assert res.converged
    truth = theta_from(p.truth)
    v = res.values
    assert abs(v["timeshift_s"] - truth[0]) < 1e-4
    # 24 frames only: focal lengths to 0.3 % here (the 0.1 % target is the benchmark's, with
    # 100 frames); the sigma test below checks them against their own uncertainty.
    assert abs(v["fx"] / truth[1] - 1) < 3e-3 and abs(v["fy"] / truth[2] - 1) < 3e-3
    assert abs(v["cx"] - truth[3]) < 2.0 and abs(v["cy"] - truth[4]) < 2.0
    assert abs(v["readout_s"] - truth[5]) < 2e-4
    assert np.all(np.abs(np.array([v["bias_x"], v["bias_y"], v["bias_z"]]) - truth[6:9]) < 1e-3)
    rot = rotation_error_rad(res.calibration.R_cam_imu, p.truth.R_cam_imu)
    assert np.degrees(np.linalg.norm(rot)) < 0.1
    assert res.holdout.n > 0 and res.holdout.mean_px < 0.3


def test_sigma_covers_the_true_error(fitted) -> None:
    p, res = fitted
    truth = dict(
        zip(
            ("timeshift_s", "fx", "fy", "cx", "cy", "readout_s"),
            theta_from(p.truth)[:6],
            strict=True,
        )
    )
    for name, t in truth.items():
        assert res.sigma[name] > 0
        assert abs(res.values[name] - t) < 4 * res.sigma[name], name
    sig = res.calibration.sigma
    assert set(sig) >= {"timeshift_cam_imu", "intrinsics", "readout_s", "gyro_bias_radps"}


def test_global_shutter_readout_at_its_bound() -> None:
    # Readout 0 (true and guessed), fitted: every Gauss-Newton step pulls it a little below 0.
    # Rejecting those steps stalled the fit at its start (cx, cy and the bias stayed at the
    # guess); the step is projected onto the bound instead.
    p = make_problem(
        seed=3,
        n_frames=16,
        dots_per_frame=40,
        endpoint_noise_px=0.1,
        readout_s=0.0,
        shift_error_s=0.01,
        focal_error=0.03,
    )
    res = calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.25))
    truth = theta_from(p.truth)
    v = res.values
    assert res.converged and res.status in ("ok", "warning")
    assert 0.0 <= v["readout_s"] < 2e-4
    assert abs(v["cx"] - truth[3]) < 2.0 and abs(v["cy"] - truth[4]) < 2.0
    assert np.all(np.abs(np.array([v["bias_x"], v["bias_y"], v["bias_z"]]) - truth[6:9]) < 1e-3)
    assert res.holdout.mean_px < 0.3


def test_flipped_and_gross_outliers_are_rejected() -> None:
    p = make_problem(
        seed=5,
        n_frames=16,
        dots_per_frame=40,
        endpoint_noise_px=0.1,
        shift_error_s=0.02,
        focal_error=0.03,
    )
    s = p.streaks
    rng = np.random.default_rng(0)
    long = np.flatnonzero(s.length_px > 8)
    flip = rng.choice(long, 25, replace=False)
    start, end = s.start.copy(), s.end.copy()
    start[flip], end[flip] = s.end[flip], s.start[flip]
    rest = np.setdiff1d(np.arange(len(s)), flip)
    gross = rng.choice(rest, 15, replace=False)
    end[gross] += rng.normal(0, 30, (15, 2))
    bad = StreakSet(start, end, s.frame_t_s, s.exposure_s, s.frame, s.streak_id, s.t0_s)
    res = calibrate(bad, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert 15 <= res.n_outliers <= 25  # the gross ones (and a few of the flipped short ones)
    assert res.n_flipped >= 20  # swapped back and used
    assert abs(res.values["timeshift_s"] - p.truth.timeshift_cam_imu_s) < 2e-4
    assert res.train.mean_px < 0.3


def test_too_few_streaks() -> None:
    p = make_problem(seed=1, n_frames=3, dots_per_frame=5)
    with pytest.raises(CalibError, match="too few streaks"):
        calibrate(p.streaks, p.gyro, p.initial)


def test_no_motion() -> None:
    p = make_problem(seed=2, n_frames=8, dots_per_frame=20, amp_radps=1e-4)
    with pytest.raises(CalibError, match="no motion"):
        calibrate(p.streaks, p.gyro, p.initial)


def test_gyro_not_covering_the_exposures() -> None:
    from blurtrack.geometry.gyro import GyroTrace

    p = make_problem(seed=4, n_frames=8, dots_per_frame=20)
    g = p.gyro
    short = GyroTrace(g.t_s[: g.t_s.size // 8], g.omega_radps[: g.t_s.size // 8])
    with pytest.raises(CalibError, match="does not cover"):
        calibrate(p.streaks, short, p.initial)


def test_contradictory_gyro_fails_loudly() -> None:
    p = make_problem(seed=6, n_frames=6, dots_per_frame=20)
    other = make_problem(seed=7, n_frames=6, dots_per_frame=20)
    # Fit quality is a status, never an exception (docs/calibration.md, failure policy).
    res = calibrate(p.streaks, other.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert res.status == "failed"
    assert any("contradict" in w for w in res.warnings)


def test_too_few_agreeing_streaks_is_a_failed_status_not_an_error() -> None:
    # 40 streaks, 16 of them with ends 30 px off: 25 agree with the model, under the 30 a
    # fit needs. That is the fit's quality (status failed, the reason among the warnings),
    # not unusable input; the same streaks without the corruption fit.
    p = make_problem(seed=5, n_frames=4, dots_per_frame=10, endpoint_noise_px=0.1)
    s = p.streaks
    rng = np.random.default_rng(0)
    end = s.end.copy()
    bad = rng.choice(len(s), 16, replace=False)
    end[bad] += rng.normal(0, 30, (16, 2))
    corrupt = StreakSet(s.start, end, s.frame_t_s, s.exposure_s, s.frame, s.streak_id, s.t0_s)
    res = calibrate(corrupt, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert res.status == "failed"
    assert any("streaks agree with the model (need 30)" in w for w in res.warnings)
    assert np.all(np.isfinite(list(res.values.values())))  # an estimate for the summary
    clean = calibrate(s, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert clean.status != "failed"
    assert not any("agree with the model" in w for w in clean.warnings)


def test_no_roll_warns_about_readout_and_principal_point() -> None:
    p = make_problem(seed=8, n_frames=8, dots_per_frame=25, roll=0.0)
    res = calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert any("roll" in w for w in res.warnings)
    assert res.status == "warning"


def test_gyro_scale_fit_removes_the_focal_bias() -> None:
    M = np.eye(3) + np.array([[4e-3, 1e-3, 0.0], [1e-3, -3e-3, 5e-4], [0.0, 5e-4, 2e-3]])
    p = make_problem(
        seed=9,
        n_frames=12,
        dots_per_frame=40,
        endpoint_noise_px=0.05,
        gyro_scale=M,
        shift_error_s=0.01,
        focal_error=0.02,
    )
    res = calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert "scale_xy" in res.fitted  # by default
    assert not any("scale/cross-axis" in w for w in res.warnings)  # no score test when fitted
    # The samples are rotated from the camera frame by R_cam_imu: compare in the IMU frame.
    got = np.array([res.values[f"scale_{a}"] for a in ("xx", "yy", "zz", "xy", "xz", "yz")])
    want = np.array([M[0, 0] - 1, M[1, 1] - 1, M[2, 2] - 1, M[0, 1], M[0, 2], M[1, 2]])
    sig = np.array([res.sigma[f"scale_{a}"] for a in ("xx", "yy", "zz", "xy", "xz", "yz")])
    assert np.all(np.abs(got - want) < np.maximum(4 * sig, 3e-4)), (got - want) / sig
    assert abs(res.values["fx"] / p.truth.camera.intrinsics[0] - 1) < 1.5e-3
    assert res.calibration.sigma["gyro_scale"][0] > 0
    np.testing.assert_allclose(
        res.calibration.gyro_scale_matrix - np.eye(3),
        [[got[0], got[3], got[4]], [got[3], got[1], got[5]], [got[4], got[5], got[2]]],
        atol=1e-15,
    )
    # Without the scale group the score test flags what the fit now absorbs.
    res0 = calibrate(
        p.streaks,
        p.gyro,
        p.initial,
        FitOptions(fit="timeshift,fx,fy,cx,cy,readout,bias,rotation", holdout_fraction=0.0),
    )
    assert np.array_equal(res0.calibration.gyro_scale_matrix, np.eye(3))


def test_scale_check_flags_a_large_unfitted_scale() -> None:
    from calib.data import relative_gyro
    from calib.fit import scale_check
    from calib.grid import GridEvaluator
    from calib.params import theta_from as th_of
    from calib.problem import ResidualModel, choose_substeps

    M = np.diag([1.0, 1.0, 1.05])  # roll-axis scale: no intrinsic can absorb it
    p = make_problem(seed=12, n_frames=10, dots_per_frame=40, endpoint_noise_px=0.02, gyro_scale=M)
    s = p.streaks
    model = ResidualModel(
        relative_gyro(p.gyro.upsampled(8), s.t0_s),
        p.truth.R_cam_imu,
        (),
        720,
        choose_substeps(s, 720, 0.05),
    )
    ev = GridEvaluator(model.gyro, model.R0_cam_imu, (), 720)
    free = tuple(range(12))
    w = np.ones(len(s))
    assert any("scale" in m for m in scale_check(ev, th_of(p.truth), s, w, free))
    assert scale_check(ev, th_of(p.truth), s, w, tuple(range(18))) == []


def test_refit_on_all_frames_and_progress_reports() -> None:
    p = make_problem(seed=6, n_frames=10, dots_per_frame=30, shift_error_s=0.01, focal_error=0.02)
    events = []
    res = calibrate(p.streaks, p.gyro, p.initial, FitOptions(), progress=events.append)
    stages = [e.stage for e in events]
    assert stages[0] == "initial search" and "coarse" in stages
    assert "fine round 1" in stages and "refit on all frames" in stages
    assert any(e.iteration > 0 and np.isfinite(e.cost) for e in events)
    assert all(b.elapsed_s >= a.elapsed_s for a, b in itertools.pairwise(events))
    # The written values are the refit's; the hold-out figures evaluate the training fit.
    assert res.holdout_fit_values is not None and res.holdout.n > 0
    assert res.values != res.holdout_fit_values
    assert res.train.n > res.holdout.n  # every frame's streaks
    alone = calibrate(p.streaks, p.gyro, p.initial, FitOptions(refit_all=False))
    assert alone.holdout_fit_values is None
    assert alone.holdout.mean_px == res.holdout.mean_px
    assert alone.values == res.holdout_fit_values


@pytest.mark.parametrize("tracked", [False, True])
def test_warm_refit_equals_a_cold_fit_on_every_frame(tracked: bool) -> None:
    # The refit starts from the training fit's estimate and outlier thresholds and runs only
    # the final stage; a cold fit on every frame (no hold-out) runs every stage from the
    # initial guess. Both minimise the same cost over the same data: they must agree far
    # inside the sigma, while the training fit alone (a fifth of the frames fewer) does not.
    p = make_problem(
        seed=21, n_frames=20, dots_per_frame=40, tracked=tracked, gyro_noise_radps=2e-3
    )
    events: list = []
    warm = calibrate(p.streaks, p.gyro, p.initial, FitOptions(), progress=events.append)
    cold = calibrate(p.streaks, p.gyro, p.initial, FitOptions(holdout_fraction=0.0))
    assert warm.residuals == cold.residuals == ("tracks" if tracked else "endpoints")
    assert warm.holdout_fit_values is not None
    z = [abs(warm.values[k] - cold.values[k]) / s for k, s in cold.sigma.items()]
    z_train = [abs(warm.holdout_fit_values[k] - cold.values[k]) / s for k, s in cold.sigma.items()]
    assert max(z) < 0.05, z
    assert max(z_train) > 0.2  # the refit moved: the comparison can tell
    assert warm.train.n == cold.train.n and warm.n_tracks == cold.n_tracks
    # The refit repeats neither the search nor the coarse stages.
    refit = [e.stage for e in events[[e.stage for e in events].index("refit on all frames") :]]
    assert refit and not any(s.startswith(("coarse", "initial", "fine")) for s in refit)
