"""Clock map: lower-envelope fit under drift, jitter, batching and bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rigs.errors import TimeSyncError
from rigs.timesync import fit_clock_map, lower_hull


def _scenario(jitter: str, seed: int, batch: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = 60_000  # one minute at 1 kHz
    t_true_ns = 5_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000  # host time of sampling
    dev_ns = np.rint((t_true_ns - 5e9) * (1 + 100e-6)).astype(np.int64) + 123_456_789
    lat = rng.uniform(0.0, 0.002, n) if jitter == "uniform" else np.abs(rng.normal(0.0, 0.002, n))
    host_ns = t_true_ns + np.rint(lat * 1e9).astype(np.int64)
    if batch > 1:  # the host stamps a whole read with the arrival of its last sample
        blocks = host_ns.reshape(-1, batch)
        host_ns = np.repeat(blocks.max(axis=1), batch)
    return dev_ns, host_ns, t_true_ns


@pytest.mark.parametrize(("jitter", "batch"), [("uniform", 1), ("halfnormal", 1), ("uniform", 8)])
def test_drift_100ppm_with_2ms_jitter_recovered_within_0p2ms(jitter: str, batch: int) -> None:
    dev_ns, host_ns, truth_ns = _scenario(jitter, seed=3, batch=batch)
    cmap = fit_clock_map(dev_ns, host_ns)
    err_s = (cmap.to_host_ns(dev_ns) - truth_ns) * 1e-9
    assert np.max(np.abs(err_s)) < 0.2e-3
    # host runs slower than the +100 ppm device: drift ~ -100 ppm
    assert cmap.drift_ppm == pytest.approx(-100.0 / (1 + 100e-6), abs=5.0)


def test_least_squares_would_fail_the_same_budget() -> None:
    """The envelope matters: a plain least-squares line is off by about the mean latency."""
    dev_ns, host_ns, truth_ns = _scenario("uniform", seed=4)
    x = (dev_ns - dev_ns[0]) * 1e-9
    coef = np.polyfit(x, (host_ns - dev_ns) * 1e-9, 1)
    ls_err = dev_ns * 1e-9 + np.polyval(coef, x) - truth_ns * 1e-9
    assert np.median(np.abs(ls_err)) > 0.5e-3


def test_exact_line_is_reproduced_and_min_latency_subtracted() -> None:
    dev_ns = np.arange(0, 10_000_000_000, 10_000_000, dtype=np.int64)
    host_ns = dev_ns + 2_000_000 + dev_ns // 20_000  # +50 ppm, 2 ms constant latency
    cmap = fit_clock_map(dev_ns, host_ns, min_latency_s=0.5e-3)
    mapped = cmap.to_host_ns(dev_ns)
    assert np.max(np.abs(mapped - (host_ns - 500_000))) <= 1
    assert cmap.drift_ppm == pytest.approx(50.0, abs=1e-6)


def test_lower_hull_is_below_all_points() -> None:
    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(0, 10, 500))
    y = rng.normal(0, 1, 500)
    h = lower_hull(x, y)
    for a, b in itertools.pairwise(h):
        slope = (y[b] - y[a]) / (x[b] - x[a])
        assert np.all(y - (y[a] + slope * (x - x[a])) >= -1e-9)


@pytest.mark.parametrize(
    ("dev", "host", "match"),
    [
        ([1], [2], "too few"),
        ([5, 5, 5], [1, 2, 3], "one device time"),
        ([1, 2], [1, 2, 3], "differ"),
    ],
)
def test_bad_input_is_rejected(dev, host, match) -> None:
    with pytest.raises(TimeSyncError, match=match):
        fit_clock_map(np.array(dev), np.array(host))


def test_conversion_maps_drifting_jittery_imu_onto_host_time(tmp_path) -> None:
    """Through the whole log -> session path: 100 ppm drift, 2 ms jitter, batched reads."""
    import cv2

    from blurtrack.io.session import load_session
    from rigs.camera_types import CameraFrame
    from rigs.convert import log_to_session
    from rigs.reclog import RecLogWriter

    dev_ns, host_ns, truth_ns = _scenario("uniform", seed=9, batch=4)
    w = RecLogWriter(tmp_path / "d.mcap", {})
    png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1].tobytes()
    w.write_frame(
        CameraFrame(0, np.zeros((8, 8), np.uint8), int(truth_ns[0]), 1000, 0, "host"), png, "png"
    )
    for a in range(0, dev_ns.size, 1000):
        sl = slice(a, a + 1000)
        w.write_imu(
            int(host_ns[sl][-1]),
            np.arange(a, a + 1000),
            dev_ns[sl] // 1000,
            host_ns[sl],
            np.zeros((1000, 3)),
            None,
        )
    w.finish()
    res = log_to_session(tmp_path / "d.mcap", tmp_path / "s")
    s = load_session(tmp_path / "s")
    assert np.max(np.abs(s.imu_t_ns - truth_ns)) < 200_000  # 0.2 ms
    assert res.clock_map["drift_ppm"] == pytest.approx(-100.0, abs=5.0)


def test_windowed_map_follows_a_changing_drift() -> None:
    """20 min at 200 Hz, drift sweeping 50 -> 150 ppm (a warming crystal), 2 ms jitter."""
    from rigs.timesync import fit_clock_map_windowed

    rng = np.random.default_rng(12)
    n = 240_000
    t_s = np.arange(n) / 200.0
    T = t_s[-1]
    dev_ns = np.rint((t_s + 50e-6 * t_s + 50e-6 * t_s**2 / T) * 1e9).astype(np.int64)
    truth_ns = 3_000_000_000 + np.rint(t_s * 1e9).astype(np.int64)
    host_ns = truth_ns + np.rint(rng.uniform(0, 2e-3, n) * 1e9).astype(np.int64)
    single = fit_clock_map(dev_ns, host_ns)
    assert np.max(np.abs(single.to_host_ns(dev_ns) - truth_ns)) > 1_000_000  # > 1 ms off
    win = fit_clock_map_windowed(dev_ns, host_ns, window_s=60.0)
    assert len(win.windows) == 20
    assert np.max(np.abs(win.to_host_ns(dev_ns) - truth_ns)) < 200_000  # < 0.2 ms
    d = win.as_dict()
    # host relative to device: -52.5 ppm in the first window, -147.5 ppm in the last
    assert d["drift_ppm_min"] < -140 and d["drift_ppm_max"] > -60


def test_windowed_map_of_a_short_recording_is_the_single_fit() -> None:
    from rigs.timesync import fit_clock_map_windowed

    dev_ns, host_ns, _ = _scenario("uniform", seed=2)
    a = fit_clock_map_windowed(dev_ns, host_ns, window_s=60.0)
    b = fit_clock_map(dev_ns, host_ns)
    assert len(a.windows) == 1
    np.testing.assert_array_equal(a.to_host_ns(dev_ns), b.to_host_ns(dev_ns))
