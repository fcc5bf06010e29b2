"""Natural-scene sigma (calib.natural.sigma): the consider term's sensitivity of the fitted
focal length to the unfitted gyro scale predicts what a refit with that scale error does,
the widened sigma never falls below the fit's own, and a scale matrix given in session.yaml
counts as known."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from blurtrack.io.session import load_session
from calib.fit import FitOptions
from calib.natural.cli import NATURAL_FIT
from calib.natural.pipeline import calibrate_natural
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session

DELTA = 0.004  # scale error put into session.yaml's guess for the refit


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_data) -> Path:
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    out = tmp_path_factory.mktemp("natsigma") / "s"
    write_session(NaturalRig(preset, 5, 24), out)
    return out


class _WithScale:
    """A session whose initial calibration carries a given gyro scale matrix."""

    def __init__(self, base: Any, M: np.ndarray) -> None:
        self._base, self._M = base, M

    def __getattr__(self, name: str) -> Any:
        return getattr(self._base, name)

    def initial_calibration(self):
        return self._base.initial_calibration().with_(gyro_scale_matrix=self._M)


def test_scale_sensitivity_predicts_a_refit_and_sigma_is_widened(session) -> None:
    s = load_session(session)
    opts = FitOptions(fit=NATURAL_FIT, holdout_fraction=0.2, shift_window_s=0.05)
    nat = calibrate_natural(s, opts, translation="none", passes=1, scale_prior="consider")
    info = nat.sigma
    assert info is not None and info["gyro_scale_sigma"] > 0
    assert len(info["gyro_scale_considered"]) == 6
    for name, part in info["parts"].items():
        assert nat.result.sigma[name] >= part["fit"] - 1e-12
        assert nat.result.sigma[name] >= part["gyro_scale"] - 1e-12
    # fx follows the scale of the gyro axis along camera y almost one to one (the
    # scale-focal trade-off); which IMU axis that is, the data say
    diag = {n: v for n, v in info["sensitivity"]["fx"].items() if n[-2] == n[-1]}
    entry = max(diag, key=lambda n: abs(diag[n]))
    sens = diag[entry]
    fx = nat.result.values["fx"]
    assert 0.5 < abs(sens) / fx < 1.5
    M = np.eye(3)
    k = "xyz".index(entry[-1])
    M[k, k] += DELTA
    known = calibrate_natural(
        _WithScale(s, M), opts, translation="none", passes=1, scale_prior="consider"
    )
    assert known.sigma is not None and known.sigma["gyro_scale_sigma"] == 0.0
    assert all(p["gyro_scale"] == 0.0 for p in known.sigma["parts"].values())
    moved = known.result.values["fx"] - fx
    predicted = sens * DELTA
    # measured: moved +1.060 px, predicted +1.098 px
    assert abs(moved - predicted) < 0.2 * abs(predicted)
    assert abs(predicted) > 0.5  # a shift to predict (2x the fit's own sigma here)
