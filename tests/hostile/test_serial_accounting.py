"""Hostile IMU streams built byte by byte: corrupted counters, repeated device times.

Every frame here is a valid frame (its CRC is computed over the damaged field), so the decoder
accepts it and only the sequencer can tell that the counter or the time is wrong. The checks are
on the bookkeeping: what arrived must equal what was kept plus what was discarded, with a reason.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from blurtrack.io.session import load_session
from rigs.convert import log_to_session
from rigs.fake_camera import VirtualCamera, VirtualCameraConfig
from rigs.imu import ImuBatch, ImuDriver
from rigs.protocol import encode_ascii, encode_binary
from rigs.recorder import Recorder, RecorderConfig
from rigs.sequence import Sequencer

RATE_HZ = 1000.0
PERIOD_US = 1000


class _Feeder:
    """The far end of a ``loop://`` port: writes ``stream`` into it from a thread (the loop
    port holds only 4 KiB) and says when the driver has decoded all of it."""

    def __init__(self, port: serial.SerialBase, stream: bytes) -> None:
        self.total = len(stream)
        self._thread = threading.Thread(target=self._write, args=(port, stream), daemon=True)
        self._thread.start()

    @staticmethod
    def _write(port: serial.SerialBase, stream: bytes) -> None:
        for i in range(0, len(stream), 1024):
            port.write(stream[i : i + 1024])

    @property
    def finite(self) -> bool:
        return True

    def drained(self, bytes_decoded: int) -> bool:
        return bytes_decoded >= self.total

    def close(self) -> None:
        self._thread.join(timeout=5.0)


def _driver(stream: bytes, rate_hz: float | None = RATE_HZ, protocol: str = "binary") -> ImuDriver:
    """The real driver reading ``stream`` from a loopback serial port."""
    port = serial.serial_for_url("loop://", timeout=0.01)
    return ImuDriver(port, "loop://", protocol, rate_hz, far_end=_Feeder(port, stream))


def _drive(
    stream: bytes, rate_hz: float | None = RATE_HZ, protocol: str = "binary"
) -> tuple[ImuBatch, dict[str, int]]:
    """Push ``stream`` through the real driver; all samples it returned and its stats."""
    drv = _driver(stream, rate_hz, protocol)
    batches = []
    deadline = time.monotonic() + 30.0
    while not drv.exhausted and time.monotonic() < deadline:
        batches.append(drv.read())
    drv.close()
    assert drv.exhausted
    cat = ImuBatch(
        index=np.concatenate([b.index for b in batches]),
        t_dev_us=np.concatenate([b.t_dev_us for b in batches]),
        host_ns=np.concatenate([b.host_ns for b in batches]),
        gyro_radps=np.concatenate([b.gyro_radps for b in batches]),
        accel_mps2=np.concatenate([b.accel_mps2 for b in batches]),
    )
    return cat, drv.stats


def _adds_up(st: dict[str, int]) -> None:
    """received = kept + duplicates + bad_counter + time_jumps_back, received = decoded."""
    assert st["received"] == st["samples"]
    assert st["received"] == (
        st["kept"] + st["duplicates"] + st["bad_counter"] + st["time_jumps_back"]
    ), st


def test_single_corrupted_counters_cost_one_sample_each() -> None:
    n = 2000  # 2 s at 1 kHz
    bad = set(range(40, n - 40, 90))  # 22 samples whose counter is garbage
    assert len(bad) == 22
    rng = np.random.default_rng(3)
    frames = []
    for k in range(n):
        counter = k if k not in bad else (k + int(rng.integers(2, 65535))) % 65536
        frames.append(encode_binary(counter, k * PERIOD_US, (k, -k, 7)))
    got, st = _drive(b"".join(frames))
    assert st["bad_counter"] == 22 and st["dropped"] == 0 and st["gaps"] == 0, st
    assert st["counter_wraps"] == 0 and st["duplicates"] == 0, st
    assert got.index.tolist() == [k for k in range(n) if k not in bad]
    assert st["kept"] == n - 22 == len(got)
    _adds_up(st)


def test_a_corrupted_counter_next_to_a_real_gap() -> None:
    # samples 100..104 lost on the wire, sample 105 arrives with a garbage counter
    ks = [k for k in range(300) if not 100 <= k <= 104]
    frames = [encode_binary(k if k != 105 else 40000, k * PERIOD_US, (1, 2, 3)) for k in ks]
    got, st = _drive(b"".join(frames))
    assert st["bad_counter"] == 1 and st["dropped"] == 5 and st["gaps"] == 1, st
    assert got.index.tolist() == [k for k in ks if k != 105]
    _adds_up(st)


def test_a_stuck_counter_with_advancing_time_is_bad_not_duplicate() -> None:
    frames = [encode_binary(k if k != 50 else 49, k * PERIOD_US, (1, 2, 3)) for k in range(100)]
    got, st = _drive(b"".join(frames))
    assert st["bad_counter"] == 1 and st["duplicates"] == 0 and st["dropped"] == 0, st
    assert len(got) == 99
    _adds_up(st)


def test_a_corrupted_device_time_is_one_bad_sample() -> None:
    frames = [
        encode_binary(k, k * PERIOD_US if k != 60 else 123_456_789, (1, 2, 3)) for k in range(100)
    ]
    got, st = _drive(b"".join(frames))
    assert st["bad_counter"] == 1 and st["dropped"] == 0 and st["gaps"] == 0, st
    assert got.t_dev_us.tolist() == [k * PERIOD_US for k in range(100) if k != 60]
    _adds_up(st)


def test_repeated_device_times_are_counted_as_duplicates() -> None:
    # a device whose clock ticks every 2 ms while it samples every 1 ms: every second sample
    # repeats the device time of the one before
    n = 400
    frames = [encode_binary(k, (k // 2) * 2 * PERIOD_US, (k, 0, 0)) for k in range(n)]
    got, st = _drive(b"".join(frames))
    assert st["duplicates"] == n // 2 and st["dropped"] == 0 and st["gaps"] == 0, st
    assert st["bad_counter"] == 0 and st["kept"] == len(got) == n // 2
    assert np.all(np.diff(got.t_dev_us) > 0)
    _adds_up(st)


def test_resent_frames_are_duplicates_and_do_not_hide_a_gap() -> None:
    ks = [0, 1, 2, 2, 2, 3, 7, 8]  # 2 resent twice; 4, 5, 6 lost
    frames = [encode_binary(k, k * PERIOD_US, (1, 2, 3)) for k in ks]
    got, st = _drive(b"".join(frames))
    assert st["duplicates"] == 2 and st["dropped"] == 3 and st["gaps"] == 1, st
    assert got.index.tolist() == [0, 1, 2, 3, 7, 8]
    _adds_up(st)


def test_ascii_repeated_times_are_duplicates() -> None:
    ts = [0, 1000, 1000, 2000, 3000, 3000, 3000, 4000]
    stream = b"".join(encode_ascii(t, (0.1, 0.2, 0.3)) for t in ts)
    got, st = _drive(stream, protocol="ascii")
    assert st["duplicates"] == 3 and st["dropped"] == 0 and len(got) == 5, st
    _adds_up(st)


def test_a_wrong_anchor_is_abandoned_after_a_few_agreeing_samples() -> None:
    # the counter jumps by 3 once and stays shifted (a device reset of the counter alone):
    # after a few samples that agree with each other the sequencer follows the new counter
    seq = Sequencer(rate_hz=RATE_HZ)
    out = [seq.push(k if k < 50 else k + 3000, k * PERIOD_US) for k in range(100)]
    kept = [o for o in out if o is not None]
    assert seq.stats.bad_counter <= 4 and len(kept) >= 96
    assert [o.t_dev_us for o in kept] == sorted({o.t_dev_us for o in kept})
    assert kept[-1].index == 99 and seq.stats.dropped == 0


def test_without_a_rate_the_first_samples_are_trusted_then_checked() -> None:
    seq = Sequencer(rate_hz=None)
    for k in range(40):
        seq.push(k, k * PERIOD_US)
    assert seq.push(20_000, 40 * PERIOD_US) is None  # the rate is now estimated: garbage
    assert seq.push(41, 41 * PERIOD_US) is not None
    assert seq.stats.bad_counter == 1 and seq.stats.dropped == 0


def test_the_session_holds_exactly_the_kept_samples(tmp_path: Path) -> None:
    n = 3000
    bad = set(range(100, n - 100, 211))
    frames = []
    for k in range(n):
        t = (k // 2) * 2 * PERIOD_US if 2000 <= k < 2200 else k * PERIOD_US
        frames.append(encode_binary(k if k not in bad else k ^ 0x5A5A, t, (k, 0, 0)))
    imu = _driver(b"".join(frames))
    img = np.zeros((24, 32), np.uint8)
    cam = VirtualCamera(
        lambda t: img, VirtualCameraConfig(fps=10, exposure_s=0.005, n_frames=3, realtime=False)
    )
    rec = Recorder(tmp_path / "rec.mcap", imu, cam, {}, RecorderConfig(flush_interval_s=0.05))
    result = rec.run()
    imu.close()
    st = result.imu_stats
    _adds_up(st)
    assert st["received"] == n and st["bad_counter"] == len(bad) and st["duplicates"] == 100
    assert st["dropped"] == 0 and st["counter_wraps"] == 0
    conv = log_to_session(tmp_path / "rec.mcap", tmp_path / "session")
    s = load_session(tmp_path / "session")
    assert conv.skipped_imu == 0 and conv.imu_samples == st["kept"] == len(s.imu_t_ns)
    assert s.meta.extra["recording"]["imu_stats"]["kept"] == st["kept"]


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    fate=st.lists(st.sampled_from("kkkkkkkkdb"), min_size=2, max_size=400),
    start=st.integers(0, 65535),
    offsets=st.lists(st.integers(64, 65536 - 64), min_size=400, max_size=400),
)
def test_sequencer_counts_bad_and_missing_samples_exactly(
    fate: list[str], start: int, offsets: list[int]
) -> None:
    """k: arrives intact, d: lost on the wire, b: arrives with a garbage counter."""
    fate[0] = "k"
    seq = Sequencer(rate_hz=RATE_HZ)
    kept = []
    for k, f in enumerate(fate):
        if f == "d":
            continue
        counter = (start + k + (offsets[k] if f == "b" else 0)) % 65536
        out = seq.push(counter, (PERIOD_US * k) % 2**32)
        assert (out is None) == (f == "b")
        if out is not None:
            kept.append(out.index - start)
    last = max(k for k, f in enumerate(fate) if f == "k")
    s = seq.stats
    assert kept == [k for k, f in enumerate(fate) if f == "k"]
    assert s.bad_counter == fate.count("b")
    assert s.dropped == fate[:last].count("d")
    assert s.received == s.kept + s.bad_counter + s.duplicates + s.time_jumps_back


def test_a_fast_device_with_jittery_stamps_keeps_every_sample() -> None:
    # 10 kHz with +-1 us stamp jitter and a nominal rate 3 % off; gaps of up to 2000 samples
    rng = np.random.default_rng(5)
    ks = np.sort(rng.choice(50_000, 20_000, replace=False))
    ks = ks[(ks < 10_000) | (ks > 12_000)]
    seq = Sequencer(rate_hz=10_300.0)
    t = [100 * int(k) + int(rng.integers(-1, 2)) for k in ks]
    out = [seq.push(int(k) % 65536, ti % 2**32) for k, ti in zip(ks, t, strict=True)]
    assert all(o is not None for o in out)
    assert [o.index for o in out if o is not None] == [int(k) for k in ks]
    assert seq.stats.dropped == int(ks[-1] - ks[0] + 1 - ks.size)


def test_a_wrong_nominal_rate_costs_only_the_first_samples() -> None:
    seq = Sequencer(rate_hz=100.0)  # mistyped: the device samples at 1 kHz
    out = [seq.push(k, k * PERIOD_US) for k in range(300)]
    assert [o.index for o in out if o is not None] == [0, *range(4, 300)]
    s = seq.stats
    assert s.bad_counter == 3 and s.reanchors == 1 and s.dropped == 0
    assert s.received == s.kept + s.bad_counter
    assert seq.push(40_000, 300 * PERIOD_US) is None  # measured now: garbage is still caught
