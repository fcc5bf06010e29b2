"""The fast truth.yaml emitter writes YAML that safe_load reads back to the same values."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from rigs.sim.errors import SimError
from rigs.sim.truthio import dump_truth, flow

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(finite, finite), min_size=0, max_size=6),
    st.integers(-(2**62), 2**62),
    st.booleans(),
)
def test_flow_round_trips(points, k, flag) -> None:
    value = {"dot": k, "centerline": [list(p) for p in points], "inside": flag}
    assert yaml.safe_load(flow(value)) == value


def test_dump_truth_round_trips_with_header_and_empty_frames() -> None:
    truth = {
        "format": "blurtrack-truth/1",
        "calibration": {"cam0": {"intrinsics": [1000.0, 1e-7, 3.0, -2.5e300]}},
        "simulator": {"preset": {"name": "x", "misalignment_deg": [1.0, 2.0]}, "seed": 3},
        "frames": [
            {
                "index": 0,
                "timestamp_ns": 10**18,
                "exposure_ns": 5,
                "t_ref_ns": 7,
                "streaks": [
                    {
                        "dot": 1,
                        "start": [0.5, 1e-12],
                        "end": [-3.0, 2.0],
                        "centerline": [[0.5, 1e-12], [-3.0, 2.0]],
                        "inside": False,
                    }
                ],
            },
            {"index": 1, "timestamp_ns": 2, "exposure_ns": 5, "t_ref_ns": 8, "streaks": []},
        ],
    }
    assert yaml.safe_load(dump_truth(truth)) == truth
    assert yaml.safe_load(dump_truth({**truth, "frames": []}))["frames"] == []
    assert yaml.safe_load(flow([np.float64(0.25), np.float64(3e-9)])) == [0.25, 3e-9]


@pytest.mark.parametrize(
    "bad", [float("nan"), float("inf"), "two words", {"a b": 1}, np.float32(1.0), None]
)
def test_flow_refuses_what_it_cannot_write_faithfully(bad) -> None:
    with pytest.raises(SimError):
        flow(bad)
