"""Sigma of translation fits (calib.natural.motion_sigma) on a simulated driving session: the
nuisance part equals the covariance of the profiled fit (travel direction re-estimated at every
parameter), the widened sigma covers the simulator's truth where the old one (travel direction
held, no clustering, no gyro scale) did not, and a known gyro scale drops the consider term."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from blurtrack.io.session import load_session
from calib.fit import FitOptions
from calib.natural.cli import NATURAL_FIT
from calib.natural.motion import MotionProblem, cauchy_weights
from calib.natural.motion_sigma import translation_sigma
from calib.natural.pipeline import calibrate_natural
from calib.natural.travel import residual_model
from calib.params import LAYOUT, THETA_NAMES, parse_fit
from calib.truth import truth_values
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

#: Seed 5 leaves bias_x and bias_z at z 6 (new sigma); seeds 0-7: docs/journal/natural.md.
SEED = 1


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, shared_data) -> dict[str, Any]:
    """A car at 3 m/s (±30 %) towards a plane 8 m away, 1 s of 320x180, fitted with travel."""
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    s = tmp_path_factory.mktemp("drivesigma") / "s"
    write_session(NaturalRig(preset, SEED, 30, depth_m=8.0, speed_mps=3.0, speed_wobble=0.3), s)
    sess = load_session(s)
    opts = FitOptions(fit=NATURAL_FIT)
    nat = calibrate_natural(sess, opts, translation="travel")
    res = nat.result
    model, centre, f = residual_model(res.initial, nat.streaks, sess.gyro(), opts)
    pb = MotionProblem(model, nat.streaks, centre, f, travel=True)
    theta = np.array([res.values[n] for n in THETA_NAMES])
    E = np.array(nat.translation["epipoles"])
    w, _ = cauchy_weights(pb.residual(theta, E), pb.usable)
    return {
        "nat": nat,
        "truth": truth_values(sess, res.initial),
        "pb": pb,
        "theta": theta,
        "E": E,
        "w": w,
        "fit_idx": parse_fit(NATURAL_FIT),
    }


def test_nuisance_part_is_the_profiled_fits_covariance(fitted) -> None:
    """The full-Jacobian (Schur complement) sigma equals the plain sigma of the residual with
    the travel direction re-estimated at every parameter value (variable projection)."""
    pb, theta, E, w = fitted["pb"], fitted["theta"], fitted["E"], fitted["w"]
    parts = fitted["nat"].sigma["parts"]
    keep = w > 0
    r0 = pb.residual(theta, E)
    cols = []
    for n in ("cx", "cy", "rot_x", "fx", "timeshift_s"):
        h = 1e-2 if n in ("fx", "cx", "cy") else 1e-6
        col = []
        for sgn in (1, -1):
            tp = theta.copy()
            tp[LAYOUT[n]] += sgn * h
            col.append(pb.residual(tp, pb.epipoles(tp, w)))
        cols.append((col[0] - col[1]) / (2 * h))
    # the other fitted parameters held at the estimate (a sub-block), both ways
    Jp = np.stack(cols, axis=1)[keep]
    sub = [THETA_NAMES.index(n) for n in ("cx", "cy", "rot_x", "fx", "timeshift_s")]
    dof = int(keep.sum()) - len(sub) - 2 * len(E)
    s2 = float(np.sum(w[keep] * r0[keep] ** 2)) / dof
    cov = s2 * np.linalg.inv((Jp * w[keep, None]).T @ Jp)
    sig_sub, info = translation_sigma(pb, theta, E, tuple(sub), w, scale_known=True)
    for k, n in enumerate(("cx", "cy", "rot_x", "fx", "timeshift_s")):
        profiled = float(np.sqrt(cov[k, k]))
        assert abs(info["parts"][n]["fit"] / profiled - 1) < 0.1, n
    # negative control: holding the travel direction understates the principal point's
    assert info["parts"]["cy"]["fit"] > 1.5 * info["parts"]["cy"]["nuisance_held"]
    assert all(parts[n]["fit"] >= parts[n]["nuisance_held"] * (1 - 1e-6) for n in parts)
    assert set(sig_sub) == {"cx", "cy", "rot_x", "fx", "timeshift_s"}


def test_sigma_covers_the_truth_and_the_old_one_did_not(fitted) -> None:
    nat, truth = fitted["nat"], fitted["truth"]
    res, parts = nat.result, nat.sigma["parts"]
    z_new = {n: (res.values[n] - truth[n]) / res.sigma[n] for n in res.sigma}
    z_old = {n: (res.values[n] - truth[n]) / parts[n]["nuisance_held"] for n in res.sigma}
    assert len(z_new) == 12
    assert sum(abs(z) <= 3 for z in z_new.values()) >= 11, z_new
    # negative control: the sigma the fit reported before leaves the truth outside 3 sigma
    assert sum(abs(z) > 3 for z in z_old.values()) >= 3, z_old
    # every part is a lower bound of the reported sigma; the scale term is there
    for n, p in parts.items():
        for k in ("fit", "pair", "block", "gyro_scale"):
            assert res.sigma[n] >= p[k] * (1 - 1e-9), (n, k)
    assert parts["fx"]["gyro_scale"] > parts["fx"]["fit"]
    assert nat.sigma["gyro_scale_considered"] and nat.sigma["nuisance_dof"] == 2


def test_known_gyro_scale_has_no_consider_term(fitted) -> None:
    f = fitted
    sig, info = translation_sigma(f["pb"], f["theta"], f["E"], f["fit_idx"], f["w"], True)
    assert info["gyro_scale_considered"] == [] and info["gyro_scale_sigma"] == 0.0
    res = f["nat"].result
    for n, s in sig.items():
        assert info["parts"][n]["gyro_scale"] == 0.0
        assert s <= res.sigma[n] * (1 + 1e-9)
    assert sig["fx"] < 0.8 * res.sigma["fx"]  # measured 0.50 px against 0.90 px
