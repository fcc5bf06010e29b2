"""Parameter vector, --fit parsing and the hold-out split: round trips and properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import calibration_from_dict, calibration_to_dict
from calib.data import holdout_mask
from calib.errors import CalibError
from calib.params import (
    DEFAULT_FIT,
    GROUPS,
    N_THETA,
    apply_theta,
    parse_fit,
    rotation_error_rad,
    scale_matrix,
    symmetric_scale_form,
    theta_from,
)
from calib.result import sigma_block

BASE = Calibration(Camera((640, 480), (500.0, 500.0, 320.0, 240.0), readout_s=0.01))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=N_THETA, max_size=N_THETA))
def test_apply_theta_round_trip(u: list[float]) -> None:
    th = theta_from(BASE)
    d = np.asarray(u)
    th[0] += 0.05 * d[0]
    th[1:5] += 20 * d[1:5]
    th[5] = 0.02 + 0.01 * d[5]
    th[6:9] = 0.05 * d[6:9]
    th[9:12] = 0.3 * d[9:12]
    th[12:18] = 0.01 * d[12:18]
    cal = apply_theta(BASE, th)
    back = theta_from(cal)
    np.testing.assert_allclose(back[:9], th[:9], atol=1e-12)
    np.testing.assert_allclose(back[12:18], th[12:18], atol=1e-15)
    np.testing.assert_array_equal(cal.gyro_scale_matrix, scale_matrix(th))
    # and through the calibration file
    np.testing.assert_allclose(
        theta_from(calibration_from_dict(calibration_to_dict(cal)))[12:18], th[12:18], atol=1e-15
    )
    np.testing.assert_allclose(
        rotation_error_rad(cal.R_cam_imu, BASE.R_cam_imu), th[9:12], atol=1e-9
    )


@given(st.lists(st.sampled_from(sorted(GROUPS)), min_size=1, max_size=9))
def test_parse_fit_selects_exactly_the_groups(names: list[str]) -> None:
    idx = parse_fit(",".join(names))
    assert idx == tuple(sorted({i for n in names for i in GROUPS[n]}))


def test_parse_fit_rejects_unknown_and_empty() -> None:
    with pytest.raises(CalibError, match="unknown"):
        parse_fit("fx,zoom")
    with pytest.raises(CalibError, match="no parameter"):
        parse_fit(" , ")


def test_apply_theta_rejects_divergence() -> None:
    th = theta_from(BASE)
    th[1] = -3.0
    with pytest.raises(CalibError, match="diverged"):
        apply_theta(BASE, th)
    th = theta_from(BASE)
    th[2] = np.nan
    with pytest.raises(CalibError):
        apply_theta(BASE, th)


@given(st.lists(st.integers(0, 60), min_size=1, max_size=300), st.floats(0.05, 0.5))
def test_holdout_is_framewise_and_near_the_fraction(frames: list[int], frac: float) -> None:
    f = np.asarray(frames)
    m = holdout_mask(f, frac)
    for k in np.unique(f):  # whole frames are in or out
        assert m[f == k].all() or not m[f == k].any()
    n = np.unique(f).size
    held = np.unique(f[m]).size
    assert held <= n // max(2, round(1 / frac)) + 1


def test_scale_matrix_and_sigma_block() -> None:
    th = np.zeros(N_THETA)
    th[12:18] = [1, 2, 3, 4, 5, 6]
    M = scale_matrix(th)
    np.testing.assert_allclose(M, M.T)
    assert M[0, 1] == 4 and M[2, 2] == 4
    blk = sigma_block({"fx": 0.5, "timeshift_s": 1e-5, "bias_y": 1e-4})
    assert blk == {
        "timeshift_cam_imu": 1e-5,
        "intrinsics": [0.5, None, None, None],
        "gyro_bias_radps": [None, 1e-4, None],
    }


def test_default_fit_is_every_group_including_the_gyro_scale() -> None:
    assert parse_fit(DEFAULT_FIT) == tuple(range(N_THETA))
    assert calibration_to_dict(apply_theta(BASE, theta_from(BASE))) == calibration_to_dict(
        BASE
    )  # S = 0: no key


def test_implausible_gyro_scale_is_a_divergence() -> None:
    th = theta_from(BASE)
    th[15] = 0.3
    with pytest.raises(CalibError, match="diverged"):
        apply_theta(BASE, th)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=12, max_size=12))
def test_symmetric_scale_form_keeps_the_measurement_model(u: list[float]) -> None:
    d = np.asarray(u)
    from blurtrack.geometry.rotation import so3_exp

    M = np.eye(3) + 0.02 * d[:9].reshape(3, 3)
    cal = BASE.with_(R_cam_imu=so3_exp(d[9:12]), gyro_scale_matrix=M)
    n = symmetric_scale_form(cal)
    np.testing.assert_allclose(n.gyro_scale_matrix, n.gyro_scale_matrix.T, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(n.gyro_scale_matrix) > 0)
    np.testing.assert_allclose(n.gyro_scale_matrix @ n.R_cam_imu.T, M @ cal.R_cam_imu.T, atol=1e-12)
