"""The recorder's IMU tail: it waits for samples that cover the last exposure, not for time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigs.clock import ManualClock
from rigs.imu import ImuBatch
from rigs.recorder import ImuProgress, Recorder, RecorderConfig

RATE_HZ = 1000
OFFSET_NS = 5_000_000_000  # host clock minus device clock


def batch(dev_ms: range, read_host_ns: int) -> ImuBatch:
    """Samples at device times ``dev_ms`` (ms), all read by the host at ``read_host_ns``."""
    n = len(dev_ms)
    return ImuBatch(
        index=np.arange(n, dtype=np.int64),
        t_dev_us=np.array([m * 1000 for m in dev_ms], dtype=np.int64),
        host_ns=np.full(n, read_host_ns, dtype=np.int64),
        gyro_radps=np.zeros((n, 3)),
        accel_mps2=np.full((n, 3), np.nan),
    )


def host_of(dev_ms: int, latency_ms: int = 0) -> int:
    return dev_ms * 1_000_000 + OFFSET_NS + latency_ms * 1_000_000


def test_progress_maps_host_instants_by_the_fastest_recent_delivery() -> None:
    p = ImuProgress(window_ns=2_000_000_000)
    assert p.device_ns_of(123) is None and not p.reaches(0)
    p.add(batch(range(0, 10), host_of(9, latency_ms=4)))
    p.add(batch(range(10, 20), host_of(19, latency_ms=1)))  # the fastest read
    p.add(batch(range(20, 30), host_of(29, latency_ms=7)))
    assert p.last_dev_ns == 29_000_000
    # a host instant maps to a device time at most the fastest latency late, never early
    assert p.device_ns_of(host_of(100)) == 100_000_000 - 1_000_000
    assert p.reaches(host_of(30)) and not p.reaches(host_of(31))
    # an empty batch changes nothing
    p.add(batch(range(0), host_of(40)))
    assert p.last_dev_ns == 29_000_000
    # the window forgets old reads: the drifted clock's recent offset decides
    p.add(batch(range(3000, 3010), host_of(3009, latency_ms=3)))
    assert p.device_ns_of(host_of(4000)) == 4000_000_000 - 3_000_000


class Board:
    """An infinite IMU whose samples the test hands to the recorder."""

    url, rate_hz, stats = "test://imu", float(RATE_HZ), {}
    finite, exhausted = False, False

    def read(self) -> ImuBatch:  # pragma: no cover - the recorder's thread is not started
        raise AssertionError

    def close(self) -> None: ...


def test_a_timed_tail_waits_for_the_backlog_that_covers_the_last_exposure(tmp_path: Path) -> None:
    clock = ManualClock(host_of(0))
    cfg = RecorderConfig(after_camera_end_s=0.3, imu_tail_timeout_s=2.0)
    rec = Recorder(tmp_path / "r.mcap", Board(), None, config=cfg, clock=clock)
    rec._imu_progress.add(batch(range(0, 1000), host_of(999, latency_ms=1)))
    camera_end_ns = host_of(1000)
    # the reader is starved: 0.35 s of wall clock pass without a sample (the old rule stopped)
    clock.advance_ns(host_of(1350) - clock.now_ns())
    assert rec._imu_done(camera_end_ns, timed=True) is False
    # the backlog arrives, still short of the tail
    rec._imu_progress.add(batch(range(1000, 1250), host_of(1360)))
    assert rec._imu_done(camera_end_ns, timed=True) is False
    rec._imu_progress.add(batch(range(1250, 1302), host_of(1370)))
    assert rec._imu_done(camera_end_ns, timed=True) is True
    assert rec._warnings == []


def test_a_stalled_imu_ends_the_tail_after_the_timeout_with_a_warning(tmp_path: Path) -> None:
    clock = ManualClock(host_of(0))
    cfg = RecorderConfig(after_camera_end_s=0.3, imu_tail_timeout_s=2.0)
    rec = Recorder(tmp_path / "r.mcap", Board(), None, config=cfg, clock=clock)
    rec._imu_progress.add(batch(range(0, 1100), host_of(1099)))
    camera_end_ns = host_of(1000)
    clock.advance_ns(host_of(3299) - clock.now_ns())
    assert rec._imu_done(camera_end_ns, timed=True) is False
    clock.advance_ns(2_000_000)
    assert rec._imu_done(camera_end_ns, timed=True) is True
    (msg,) = rec._warnings
    assert "IMU samples to +0.099 s past the camera's end" in msg and "0.3 s" in msg
