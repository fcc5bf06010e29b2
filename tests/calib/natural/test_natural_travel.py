"""Translation fits (calib.natural.travel) get a hold-out like rotation-only fits: whole frame
pairs left out of the fit, predicted by its calibration with their own refitted travel
direction; a wrong calibration is not absorbed by that nuisance (negative control)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from blurtrack.io.session import load_session
from calib.data import holdout_mask
from calib.fit import FitOptions
from calib.natural.cli import NATURAL_FIT
from calib.natural.pipeline import calibrate_natural
from calib.natural.travel import predict_held_out, residual_model
from calib.params import LAYOUT, THETA_NAMES
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session


@pytest.fixture(scope="module")
def drive(tmp_path_factory, shared_data) -> dict[str, Any]:
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    s = tmp_path_factory.mktemp("drivehold") / "s"
    write_session(NaturalRig(preset, 3, 30, depth_m=8.0, speed_mps=3.0, speed_wobble=0.3), s)
    sess = load_session(s)
    opts = FitOptions(fit=NATURAL_FIT)
    return {"sess": sess, "opts": opts, "nat": calibrate_natural(sess, opts, translation="auto")}


def test_travel_fit_has_a_hold_out_of_whole_frame_pairs(drive) -> None:
    nat, opts = drive["nat"], drive["opts"]
    res = nat.result
    assert nat.translation["mode"] == "travel"
    held = holdout_mask(nat.streaks.frame, opts.holdout_fraction)
    assert 0 < res.holdout.n <= res.holdout_all.n <= int(held.sum())
    assert res.holdout_all.n > 0.9 * held.sum()  # all pairs have enough tracks
    # predicted about as well as the training tracks are fitted (no overfitting)
    assert res.holdout.median_px < 1.5 * res.train.median_px
    # what was written is the refit on every pair, from the training fit's estimate
    assert res.holdout_fit_values is not None
    assert res.holdout_fit_values != res.values
    assert res.train.n + res.n_outliers == len(nat.streaks)
    assert not any("no hold-out" in w for w in res.warnings)


def test_wrong_calibration_is_not_absorbed_by_the_refitted_translation(drive) -> None:
    nat, sess, opts = drive["nat"], drive["sess"], drive["opts"]
    res = nat.result
    held = holdout_mask(nat.streaks.frame, opts.holdout_fraction)
    test = nat.streaks.subset(held)
    model, centre, f = residual_model(res.initial, nat.streaks, sess.gyro(), opts)
    theta = np.array([res.holdout_fit_values[n] for n in THETA_NAMES])
    good = predict_held_out(model, test, theta, centre, f, travel=True)
    assert np.median(np.abs(good.residual_px[good.usable])) == pytest.approx(
        res.holdout_all.median_px
    )
    # measured on this session: 0.076 px; +3 ms 0.27 px, fx +10 % 0.17 px, the rotation-only
    # fit's calibration 0.27 px
    rot = np.array([nat.rotation_only.values[n] for n in THETA_NAMES])
    wrongs = [rot]
    for name, delta in (("timeshift_s", 3e-3), ("fx", 0.1 * theta[LAYOUT["fx"]])):
        wrongs.append(theta.copy())
        wrongs[-1][LAYOUT[name]] += delta
    for wrong in wrongs:
        bad = predict_held_out(model, test, wrong, centre, f, travel=True)
        assert np.median(np.abs(bad.residual_px[bad.usable])) > 1.5 * res.holdout_all.median_px


def test_no_hold_out_when_asked(drive) -> None:
    """``--holdout 0``: the fit on every pair from both starts, no hold-out, a warning."""
    from calib.natural.travel import refit_with_translation

    nat, sess = drive["nat"], drive["sess"]
    rot = replace(nat, result=nat.rotation_only, rotation_only=None)
    opts = replace(drive["opts"], holdout_fraction=0.0)
    out = refit_with_translation(rot, sess.gyro(), opts, "travel").result
    assert out.holdout.n == 0 and out.holdout_fit_values is None
    assert any("no hold-out" in w for w in out.warnings)
