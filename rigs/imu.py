"""The serial IMU driver: bytes from pyserial to timestamped, unwrapped samples.

``open_imu(url)`` picks the transport from the URL through :data:`IMU_SCHEMES` (``serial://``,
any pyserial URL such as ``loop://`` or ``socket://``, and ``sim://imu`` for the virtual board
on a pseudo-terminal) and returns an :class:`ImuSource`; the recorder and everything above it
see only that protocol, never which device is behind it.
Each :meth:`ImuDriver.read` returns the samples completed by the bytes read, stamped with the
host time of the read; :mod:`rigs.timesync` later turns device time into host time.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import serial

from rigs.clock import Clock, MonotonicClock
from rigs.decoder import PROTOCOLS, StreamDecoder
from rigs.errors import DeviceDisconnectedError, DeviceError, DeviceUrlError
from rigs.fake_imu import ImuFaults, MotionFn, VirtualImu, VirtualImuConfig, sine_motion
from rigs.protocol import MAX_FRAME_BYTES
from rigs.sequence import Sequencer
from rigs.urls import DeviceUrl, SchemeRegistry

PYSERIAL_SCHEMES = ("loop", "socket", "rfc2217", "spy", "alt", "hwgrep")


@dataclass(frozen=True)
class ImuBatch:
    """Samples of one read. index: (N,) int64 unwrapped counter; t_dev_us: (N,) int64 unwrapped
    device time, us; host_ns: (N,) int64 host time of the read; gyro_radps: (N, 3);
    accel_mps2: (N, 3), NaN where the device sent no acceleration."""

    index: np.ndarray
    t_dev_us: np.ndarray
    host_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray

    def __len__(self) -> int:
        return int(self.index.size)


class ImuSource(Protocol):
    """What the recorder needs from an IMU, real or virtual."""

    url: str
    rate_hz: float | None
    min_latency_s: float  # the transport's least latency, recorded in the log metadata

    def read(self) -> ImuBatch:
        """Samples completed since the last read (blocks up to the source's timeout)."""
        ...

    @property
    def finite(self) -> bool:
        """True when the source ends by itself (a log, a board with a sample limit)."""
        ...

    @property
    def exhausted(self) -> bool:
        """True once a finite source has delivered everything; always False otherwise."""
        ...

    @property
    def stats(self) -> dict[str, int]: ...

    def close(self) -> None: ...


class StreamEnd(Protocol):
    """The far end of a port that knows when it has sent everything (a virtual board)."""

    @property
    def finite(self) -> bool: ...

    def drained(self, bytes_decoded: int) -> bool:
        """True once everything it sent has been decoded (``bytes_decoded`` bytes so far)."""
        ...

    def close(self) -> None: ...


class ImuDriver:
    """Reads and decodes an open pyserial port (an :class:`ImuSource`).

    ``far_end`` is what sits at the other end of the port when the driver owns it (the virtual
    board of ``sim://imu``): it says whether the stream is finite and when it is drained, and
    is closed with the driver. Real ports have none: they are infinite.
    """

    def __init__(
        self,
        port: serial.SerialBase,
        url: str,
        protocol: str = "binary",
        rate_hz: float | None = None,
        clock: Clock | None = None,
        min_latency_s: float = 0.0,
        far_end: StreamEnd | None = None,
    ) -> None:
        self.port = port
        self.url = url
        self.decoder = StreamDecoder(protocol)
        self.sequencer = Sequencer(rate_hz)
        self.clock = clock or MonotonicClock()
        self.min_latency_s = min_latency_s
        self.far_end = far_end
        self.rate_hz = rate_hz

    def read(self) -> ImuBatch:
        """Block up to the port timeout; raise DeviceDisconnectedError if the port vanished."""
        try:
            waiting = self.port.in_waiting
            data = self.port.read(waiting or 1)
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnectedError(f"IMU {self.url} disconnected: {exc}") from None
        host_ns = self.clock.now_ns()
        rows: list[tuple[int, int, tuple[float, ...], tuple[float, ...] | None]] = []
        for s in self.decoder.feed(data):
            seq = self.sequencer.push(s.counter, s.t_us)
            if seq is not None:
                rows.append((seq.index, seq.t_dev_us, s.gyro_radps, s.accel_mps2))
        n = len(rows)
        nan3 = (np.nan, np.nan, np.nan)
        return ImuBatch(
            index=np.array([r[0] for r in rows], dtype=np.int64),
            t_dev_us=np.array([r[1] for r in rows], dtype=np.int64),
            host_ns=np.full(n, host_ns, dtype=np.int64),
            gyro_radps=np.array([r[2] for r in rows], dtype=np.float64).reshape(n, 3),
            accel_mps2=np.array([r[3] or nan3 for r in rows], dtype=np.float64).reshape(n, 3),
        )

    @property
    def finite(self) -> bool:
        return self.far_end is not None and self.far_end.finite

    @property
    def exhausted(self) -> bool:
        end = self.far_end
        return end is not None and end.drained(self.decoder.stats.bytes_in)

    @property
    def stats(self) -> dict[str, int]:
        return {**self.decoder.stats.as_dict(), **self.sequencer.stats.as_dict()}

    def close(self) -> None:
        try:
            self.port.close()
        finally:
            if self.far_end is not None:
                self.far_end.close()


def _sim_config(u: DeviceUrl) -> VirtualImuConfig:
    u.check_keys(
        {
            "rate",
            "protocol",
            "seed",
            "flip",
            "drop",
            "garbage",
            "pause",
            "unplug",
            "drift_ppm",
            "noise",
            "realtime",
            "samples",
            "accel",
            "counter_start",
            "t0_us",
        }
    )
    pause_at, pause_s = None, 0.0
    if "pause" in u.params:  # pause=AT:SECONDS
        try:
            at, dur = u.params["pause"].split(":")
            pause_at, pause_s = float(at), float(dur)
        except ValueError:
            raise DeviceUrlError(f"{u.url}: pause must be AT_S:DURATION_S") from None
    try:
        faults = ImuFaults(
            flip=u.get_float("flip", 0.0, 0.0, 0.5),
            drop=u.get_float("drop", 0.0, 0.0, 0.5),
            garbage=u.get_float("garbage", 0.0, 0.0, 0.5),
            pause_at_s=pause_at,
            pause_s=pause_s,
            unplug_at_s=u.get_opt_float("unplug", 0.0, 1e7),
        )
        samples = u.get_int("samples", -1, -1, 10**9)
        return VirtualImuConfig(
            rate_hz=u.get_float("rate", 1000.0, 200.0, 1000.0),
            protocol=u.get_str("protocol", "binary", ("binary", "ascii")),
            accel=u.get_int("accel", 1, 0, 1) == 1,
            counter_start=u.get_int("counter_start", 0, 0, 65535),
            t0_us=u.get_int("t0_us", 0, 0, 2**32 - 1),
            drift_ppm=u.get_float("drift_ppm", 0.0, -1000.0, 1000.0),
            noise_radps=u.get_float("noise", 0.0, 0.0, 10.0),
            seed=u.get_int("seed", 0, 0, 2**31),
            realtime=u.get_int("realtime", 1, 0, 1) == 1,
            n_samples=None if samples < 0 else samples,
            faults=faults,
        )
    except ValueError as exc:
        raise DeviceUrlError(f"{u.url}: {exc}") from None


def _rig_config(u: DeviceUrl, clock: Clock | None) -> tuple[VirtualImuConfig, MotionFn]:
    """A board sampling a rigs.sim rig (rate from the rig's preset; see rigs.sim.shared_rig)."""
    from rigs.sim.shared_rig import rig_from_params

    if "rate" in u.params or "samples" in u.params:
        raise DeviceUrlError(f"{u.url}: with rig=..., rate and samples come from the rig")
    shared = rig_from_params(u.url, u.params, clock)
    rest = {k: v for k, v in u.params.items() if k not in ("rig", "frames")}
    rest.update(rate=repr(shared.imu_rate_hz), samples=str(shared.imu_samples()))
    cfg = _sim_config(DeviceUrl(u.url, u.scheme, u.target, rest))
    return dataclasses.replace(cfg, origin_ns=shared.imu_origin_ns), shared.omega_at


#: IMU openers by URL scheme: ``opener(url, clock, motion, read_timeout_s) -> ImuSource``.
IMU_SCHEMES: SchemeRegistry[ImuSource] = SchemeRegistry("IMU")


def open_imu(
    url: str,
    clock: Clock | None = None,
    motion: MotionFn | None = None,
    read_timeout_s: float = 0.05,
) -> ImuSource:
    """Open the IMU named by ``url``; ``motion`` drives a ``sim://imu`` board (default: sines)."""
    return IMU_SCHEMES.open(url, clock, motion, read_timeout_s)


@IMU_SCHEMES.register("sim")
def _open_sim(
    u: DeviceUrl, clock: Clock | None, motion: MotionFn | None, read_timeout_s: float
) -> ImuDriver:
    """The virtual board on a pseudo-terminal, read through pyserial like a real one."""
    if u.target != "imu":
        raise DeviceUrlError(f"{u.url}: the simulated IMU is sim://imu")
    if "rig" in u.params:
        cfg, motion = _rig_config(u, clock)
    else:
        cfg = _sim_config(u)
    device = VirtualImu(motion or sine_motion(), cfg, clock=None)
    path = device.open_pty()
    try:
        port = serial.Serial(path, baudrate=921600, timeout=read_timeout_s)
    except serial.SerialException as exc:
        device.stop()
        raise DeviceError(f"cannot open the virtual IMU's pty {path}: {exc}") from None
    device.start()
    return ImuDriver(port, u.url, cfg.protocol, cfg.rate_hz, clock, 0.0, device)


@IMU_SCHEMES.register("serial")
def _open_serial(
    u: DeviceUrl, clock: Clock | None, motion: MotionFn | None, read_timeout_s: float
) -> ImuDriver:
    u.check_keys({"protocol", "rate", "baud"})
    protocol = u.get_str("protocol", "binary", PROTOCOLS)
    rate = u.get_opt_float("rate", 1.0, 10_000.0)
    baud = u.get_int("baud", 921600, 1200, 20_000_000)
    if not u.target:
        raise DeviceUrlError(f"{u.url}: no serial device path")
    try:
        port = serial.Serial(u.target, baudrate=baud, timeout=read_timeout_s)
    except (serial.SerialException, ValueError) as exc:
        raise DeviceError(f"cannot open IMU port {u.target}: {exc}") from None
    # one frame's time on the wire (10 bits per byte) is the least possible latency
    return ImuDriver(port, u.url, protocol, rate, clock, MAX_FRAME_BYTES * 10 / baud)


@IMU_SCHEMES.register(*PYSERIAL_SCHEMES)
def _open_pyserial_url(
    u: DeviceUrl, clock: Clock | None, motion: MotionFn | None, read_timeout_s: float
) -> ImuDriver:
    """Any other transport pyserial knows by URL (``loop://``, ``socket://HOST:PORT``, ...)."""
    u.check_keys({"protocol", "rate"})
    protocol = u.get_str("protocol", "binary", PROTOCOLS)
    rate = u.get_opt_float("rate", 1.0, 10_000.0)
    bare = u.url.split("?", 1)[0]
    try:
        port = serial.serial_for_url(bare, timeout=read_timeout_s)
    except (serial.SerialException, ValueError) as exc:
        raise DeviceError(f"cannot open IMU {bare}: {exc}") from None
    return ImuDriver(port, u.url, protocol, rate, clock)
