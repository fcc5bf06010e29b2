"""The IMU driver against the virtual board on a real pseudo-terminal.

The board runs with realtime=0 (as fast as the reader reads) so that nothing depends on the
machine's load; every loop is bounded by a generous deadline and assertions are on data only.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import serial

from rigs.errors import DeviceDisconnectedError, DeviceError, DeviceUrlError
from rigs.imu import ImuBatch, ImuDriver, open_imu
from rigs.protocol import encode_binary

DEADLINE_S = 60.0


def drain(driver: ImuDriver) -> list[ImuBatch]:
    batches = []
    end = time.monotonic() + DEADLINE_S
    dev = driver.far_end
    assert dev is not None
    while time.monotonic() < end:
        batches.append(driver.read())
        # the pty moves bytes asynchronously: done when every byte sent has been decoded
        if dev.finished.is_set() and driver.decoder.stats.bytes_in >= dev.bytes_sent:
            return batches
    raise AssertionError("virtual IMU did not finish in time")


def concat(batches: list[ImuBatch]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.concatenate([b.index for b in batches]),
        np.concatenate([b.t_dev_us for b in batches]),
        np.concatenate([b.gyro_radps for b in batches]),
    )


def test_one_percent_byte_corruption_loses_only_damaged_frames() -> None:
    n = 4000
    drv = open_imu(
        f"sim://imu?rate=1000&realtime=0&samples={n}&flip=0.01&seed=7"
        "&counter_start=63000&t0_us=4293000000"
    )
    try:
        index, t_dev_us, gyro = concat(drain(drv))
        dev = drv.far_end
        sent_k = dev.sent_index
        assert sent_k.size == n
        got_k = index - 63000  # unwrapped counter back to sample number
        damaged = dev.damaged
        assert len(damaged) > 0.2 * n  # 1 % of bytes hits about 30 % of 36-byte frames
        assert set(got_k.tolist()) == set(range(n)) - damaged
        np.testing.assert_array_equal(gyro, dev.sent_gyro_radps[got_k])  # bit-exact values
        sent_t = dev.sent_t_us[got_k]
        np.testing.assert_array_equal(t_dev_us % 2**32, sent_t)
        assert np.all(np.diff(t_dev_us) > 0)  # unwrapped across the 2**32 us wrap
        stats = drv.stats
        interior = {k for k in damaged if got_k.min() < k < got_k.max()}
        assert stats["dropped"] == len(interior)
        assert stats["counter_wraps"] == 1 and stats["time_wraps"] == 1
        assert stats["crc_errors"] >= 0.7 * len(damaged)
        assert stats["samples"] == got_k.size
    finally:
        drv.close()


def test_dropped_bytes_and_garbage_bursts() -> None:
    drv = open_imu("sim://imu?rate=500&realtime=0&samples=3000&drop=0.003&garbage=0.05&seed=2")
    try:
        index, _, gyro = concat(drain(drv))
        dev = drv.far_end
        assert set(index.tolist()) == set(range(3000)) - dev.damaged
        np.testing.assert_array_equal(gyro, dev.sent_gyro_radps[index])
        assert drv.stats["resyncs"] > 50 and drv.stats["skipped_bytes"] > 0
    finally:
        drv.close()


def test_ascii_protocol_with_bit_flips() -> None:
    drv = open_imu("sim://imu?rate=200&realtime=0&samples=1500&protocol=ascii&flip=0.0005&seed=5")
    try:
        _index, t_dev_us, gyro = concat(drain(drv))
        dev = drv.far_end
        sent_t = dev.sent_t_us
        pos = np.searchsorted(sent_t, t_dev_us)
        np.testing.assert_array_equal(sent_t[pos], t_dev_us)
        np.testing.assert_array_equal(gyro, dev.sent_gyro_radps[pos])
        missing = set(range(1500)) - set(pos.tolist())
        assert missing <= dev.damaged | {k + 1 for k in dev.damaged}
        assert drv.stats["crc_errors"] + drv.stats["malformed"] > 0
        # gaps come from time steps at the nominal rate
        assert drv.stats["dropped"] == len({k for k in missing if pos.min() < k < pos.max()})
    finally:
        drv.close()


def test_unplug_raises_disconnected_after_a_clean_prefix() -> None:
    drv = open_imu("sim://imu?rate=1000&realtime=0&unplug=1.5&seed=1")
    got: list[ImuBatch] = []
    try:
        with pytest.raises(DeviceDisconnectedError, match="disconnected"):
            end = time.monotonic() + DEADLINE_S
            while time.monotonic() < end:
                got.append(drv.read())
        index, _, gyro = concat(got)
        assert index.size > 0 and np.array_equal(index, np.arange(index.size))
        np.testing.assert_array_equal(gyro, drv.far_end.sent_gyro_radps[: index.size])
        assert drv.far_end.unplugged.is_set() and drv.far_end.sent_index.size == 1500
    finally:
        drv.close()


def test_loop_url_decodes_what_is_written() -> None:
    drv = open_imu("loop://?rate=1000")
    try:
        frames = b"".join(encode_binary(k, 1000 * k, (k, -k, 2 * k)) for k in range(10))
        drv.port.write(b"\x00\x01" + frames)
        got = []
        end = time.monotonic() + DEADLINE_S
        while sum(len(b) for b in got) < 10 and time.monotonic() < end:
            got.append(drv.read())
        index, _, gyro = concat(got)
        assert index.tolist() == list(range(10))
        assert gyro[3].tolist() == [3e-6, -3e-6, 6e-6]
        assert drv.stats["skipped_bytes"] == 2
    finally:
        drv.close()


@pytest.mark.parametrize(
    ("url", "error", "match"),
    [
        ("sim://imu?rate=50", DeviceUrlError, "outside"),
        ("sim://imu?colour=red", DeviceUrlError, "unknown option"),
        ("sim://cam", DeviceUrlError, "sim://imu"),
        ("serial:///dev/does-not-exist-blurtrack", DeviceError, "cannot open"),
        ("serial:///dev/ttyS0?protocol=morse", DeviceUrlError, "protocol"),
        ("ftp://x", DeviceUrlError, "unknown IMU scheme"),
        ("/dev/ttyUSB0", DeviceUrlError, "not a device URL"),
        ("sim://imu?pause=3", DeviceUrlError, "AT_S:DURATION_S"),
    ],
)
def test_bad_urls(url: str, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        open_imu(url)


def test_serial_exception_type_is_wrapped() -> None:
    class Broken(serial.serial_for_url("loop://").__class__):
        def read(self, size: int = 1) -> bytes:
            raise serial.SerialException("gone")

    port = Broken("loop://")
    drv = ImuDriver(port, "loop://")
    with pytest.raises(DeviceDisconnectedError, match="gone"):
        drv.read()
    drv.close()


def test_pause_delivers_every_sample_late_in_a_burst() -> None:
    drv = open_imu("sim://imu?rate=500&samples=400&pause=0.2:0.4&seed=4")
    try:
        batches = drain(drv)
        index, _, gyro = concat(batches)
        np.testing.assert_array_equal(index, np.arange(400))
        np.testing.assert_array_equal(gyro, drv.far_end.sent_gyro_radps)
        assert drv.stats["dropped"] == 0
        assert drv.far_end.pauses == 1  # the board did stall once, and nothing was lost
    finally:
        drv.close()


def test_recorder_waits_for_any_finite_source_through_the_protocol() -> None:
    # A finite source that is not the virtual board: the recorder must wait for it by the
    # protocol alone (finite, exhausted), and stop waiting for an infinite one after the grace.
    from rigs.clock import ManualClock
    from rigs.recorder import Recorder, RecorderConfig

    class Replay:
        url, rate_hz, stats = "replay://x", 200.0, {}
        finite, exhausted = True, False

        def read(self):  # pragma: no cover - not read here
            raise AssertionError

        def close(self) -> None: ...

    clock = ManualClock()
    rec = Recorder("unused.mcap", Replay(), None, config=RecorderConfig(), clock=clock)
    clock.advance_ns(10**10)
    assert rec._imu_done(0) is False
    src = Replay()
    src.exhausted = True
    assert Recorder("unused.mcap", src, None, config=RecorderConfig(), clock=clock)._imu_done(0)
    src = Replay()
    src.finite = False
    assert Recorder("unused.mcap", src, None, config=RecorderConfig(), clock=clock)._imu_done(0)
