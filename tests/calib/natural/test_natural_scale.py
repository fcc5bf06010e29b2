"""MAP gyro-scale fit of natural scenes (calib.natural.scale): a vanishing prior sigma gives
the fit with the scale unfitted, a flat one the free fit; on a simulated gyro with a scale
error the posterior covers the truth; a known or freely fitted scale gets no prior, and a bad
choice is refused before any work."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from blurtrack.geometry.calibration import Calibration
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.session import load_session
from calib.errors import CalibError
from calib.fit import FitOptions, calibrate
from calib.natural.cli import NATURAL_FIT
from calib.natural.pipeline import calibrate_natural
from calib.natural.scale import (
    SCALE_PRIORS,
    natural_sigma_fit,
    prior_sigma,
    scale_is_known,
    with_scale_prior,
)
from calib.natural.scene import SCENE_MIN_CELLS
from calib.natural.sigma import GYRO_SCALE_SIGMA, SCALE_NAMES
from calib.params import rotation_error_rad, scale_entries
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

OPTS = FitOptions(fit=NATURAL_FIT, holdout_fraction=0.2, shift_window_s=0.05)
#: calibrate_natural's options of its own fits (what with_scale_prior is handed)
FIT_OPTS = replace(OPTS, shift_window_s=0.02, residuals="endpoints")


@pytest.fixture(scope="module")
def case(tmp_path_factory, shared_data) -> dict[str, Any]:
    """A small simulated far scene (the realistic preset's 0.3 % gyro scale error) fitted
    with the scale unfitted (``consider``)."""
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    out = tmp_path_factory.mktemp("natscale") / "s"
    write_session(NaturalRig(preset, 3, 30), out)
    s = load_session(out)
    nat = calibrate_natural(s, OPTS, translation="none", passes=1, scale_prior="consider")
    truth = calibration_from_dict(s.truth["calibration"], source="truth.yaml")
    M = np.array(s.truth["simulator"]["gyro"]["scale_matrix"], float)
    U, _, Vt = np.linalg.svd(M)
    return {
        "session": s,
        "nat": nat,
        "truth": truth,
        "M": M,
        "R_true": truth.R_cam_imu @ (U @ Vt).T,
    }


def _errors(cal: Calibration, case: dict[str, Any]) -> dict[str, float]:
    k, kt = cal.camera.intrinsics, case["truth"].camera.intrinsics
    rv = rotation_error_rad(cal.R_cam_imu, case["R_true"])
    se = scale_entries(cal.gyro_scale_matrix) - scale_entries(case["M"])
    return {
        "fx": k[0] - kt[0], "fy": k[1] - kt[1], "cx": k[2] - kt[2], "cy": k[3] - kt[3],
        "rot_x": rv[0], "rot_y": rv[1], "rot_z": rv[2],
        **{n: float(v) for n, v in zip(SCALE_NAMES, se, strict=True)},
    }  # fmt: skip


def test_tiny_prior_is_the_unfitted_fit_and_a_flat_one_the_free_fit(case) -> None:
    nat, s = case["nat"], case["session"]
    res, gyro = nat.result, s.gyro()
    assert nat.sigma is not None and nat.sigma["gyro_scale"] == "consider"
    tight, _ = with_scale_prior(res, nat.streaks, gyro, FIT_OPTS, 1e-8)
    # the same fit up to the MAP fit's own inlier classification (measured: within 0.05 sigma)
    for n in res.sigma:
        assert abs(tight.values[n] - res.values[n]) < 0.1 * res.sigma[n], n
    assert all(abs(tight.values[n]) < 1e-7 for n in SCALE_NAMES)
    free = calibrate(nat.streaks, gyro, res.initial, replace(FIT_OPTS, fit=NATURAL_FIT + ",scale"))
    assert all(n in free.sigma for n in SCALE_NAMES)
    flat, _ = with_scale_prior(res, nat.streaks, gyro, FIT_OPTS, 1.0)
    # measured: within 0.4 sigma of calibrate's free fit (its own outlier rounds), which
    # moved fx and scale_xx by 5 sigma from the unfitted fit
    for n in free.sigma:
        assert abs(flat.values[n] - free.values[n]) < 0.5 * free.sigma[n], n
    for n in ("fx", "scale_xx"):
        assert abs(free.values[n] - res.values[n]) > 3 * free.sigma[n]
        assert abs(flat.values[n] - res.values[n]) > 3 * free.sigma[n]


def test_posterior_covers_the_true_scale_and_the_prior_holds_it(case) -> None:
    nat, s = case["nat"], case["session"]
    assert np.max(np.abs(scale_entries(case["M"]))) > 1e-3  # a scale error to find
    m, info = natural_sigma_fit(nat.result, nat.streaks, s.gyro(), FIT_OPTS, "map")
    assert info["gyro_scale"] == "map" and info["gyro_scale_sigma"] == GYRO_SCALE_SIGMA
    # 320×180 spans ~22 scene cells of 64 px: too few for the scene sandwich (calib.natural.scene)
    assert 1 < info["scene_cells"] < SCENE_MIN_CELLS
    assert all("scene" not in p for p in info["parts"].values())
    assert set(SCALE_NAMES) <= set(m.fitted)
    err = _errors(m.calibration, case)
    # issue 13's criterion: the truth inside 3 sigma in at least 90 % of the estimates
    # (measured here: 12 of 13, cx at 3.1 sigma as with the true scale given)
    inside = [abs(e) <= 3 * m.sigma[n] for n, e in err.items()]
    assert sum(inside) >= 0.9 * len(inside), {n: e / m.sigma[n] for n, e in err.items()}
    assert all(abs(err[n]) <= 3 * m.sigma[n] for n in (*SCALE_NAMES, "fx", "fy"))
    # fx nearer the truth than with the scale left at the identity (1.45 -> 0.98 px)
    assert abs(err["fx"]) < abs(_errors(nat.result.calibration, case)["fx"])
    for n in SCALE_NAMES:  # the posterior is never wider than the prior
        assert m.sigma[n] <= prior_sigma(n) * (1 + 1e-6)
    # the unfitted scale's consider term was the larger: the data moved the scale
    assert m.sigma["fx"] < nat.result.sigma["fx"]
    # the calibration file's sigma block is the posterior's; the residual statistics are
    # the data's alone (prior rows left out): their rms is of track errors in pixels
    assert m.calibration.sigma["intrinsics"][0] == m.sigma["fx"]
    assert len(m.calibration.sigma["gyro_scale"]) == 6
    assert 0 < m.train.rms_px < 1.0 and m.holdout.n > 0
    assert m.holdout_fit_values is not None


def test_known_or_freely_fitted_scale_gets_no_prior(case) -> None:
    nat, s = case["nat"], case["session"]
    res = nat.result
    known = replace(res, initial=res.initial.with_(gyro_scale_matrix=case["M"]))
    assert scale_is_known(known) and not scale_is_known(res)
    with pytest.raises(CalibError, match="unknown scale unfitted"):
        with_scale_prior(known, nat.streaks, s.gyro(), FIT_OPTS)
    out, info = natural_sigma_fit(known, nat.streaks, s.gyro(), FIT_OPTS, "map")
    assert info["gyro_scale"] == "known"
    assert not set(SCALE_NAMES) & set(out.fitted)
    assert out.values == known.values  # the fit itself untouched
    assert out.calibration.sigma["intrinsics"][0] == out.sigma["fx"]  # the file says the same
    free = replace(res, fitted=res.fitted + SCALE_NAMES)
    with pytest.raises(CalibError, match="unknown scale unfitted"):
        with_scale_prior(free, nat.streaks, s.gyro(), FIT_OPTS)


def test_bad_scale_prior_refused_before_tracking(case) -> None:
    class _NoFrames:
        @property
        def frames(self) -> Any:
            raise AssertionError("read the frames")

    with pytest.raises(CalibError, match="gyro scale prior must be one of"):
        calibrate_natural(_NoFrames(), OPTS, scale_prior="flat")
    with pytest.raises(CalibError, match="prior sigma must be positive"):
        with_scale_prior(
            case["nat"].result, case["nat"].streaks, case["session"].gyro(), FIT_OPTS, 0.0
        )


def test_cli_choices_match_the_module() -> None:
    import argparse

    from calib.natural.cli import add_natural_args

    p = argparse.ArgumentParser()
    add_natural_args(p)
    (action,) = [a for a in p._actions if a.dest == "gyro_scale_prior"]
    assert tuple(action.choices or ()) == SCALE_PRIORS
    assert action.default == "map"
