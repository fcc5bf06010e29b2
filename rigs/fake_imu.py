"""A virtual IMU board that speaks the BlurTrack protocol over a real pseudo-terminal.

The device side owns the pty master; drivers open the slave by its path exactly as they open
``/dev/ttyUSB0``. Samples follow any motion source ``omega_at(t_s (M,)) -> (M, 3)`` rad/s. The
faults (flipped bits, lost bytes, garbage bursts, pauses, unplugging) are drawn from a seeded
generator, and the device keeps a truth log of what it sent and which frames it damaged, so tests
can compare the recording with it exactly.
"""

from __future__ import annotations

import os
import select
import threading
import tty
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigs.clock import Clock, MonotonicClock
from rigs.errors import DeviceError, RigConfigError
from rigs.protocol import (
    ACCEL_SCALE_MPS2,
    COUNTER_MODULUS,
    GYRO_SCALE_RADPS,
    encode_ascii,
    encode_binary,
)

MotionFn = Callable[[np.ndarray], np.ndarray]
GRAVITY_MPS2 = 9.80665
_BATCH = 64


def sine_motion(
    amplitude_radps: tuple[float, float, float] = (0.6, 0.4, 0.3),
    freq_hz: tuple[float, float, float] = (1.3, 2.1, 0.7),
) -> MotionFn:
    """A hand shake made of one sinusoid per axis: ``omega_at(t_s (M,)) -> (M, 3)`` rad/s."""
    amp = np.asarray(amplitude_radps, dtype=float)
    freq = np.asarray(freq_hz, dtype=float)

    def omega_at(t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)[:, None]
        return amp * np.sin(2.0 * np.pi * freq * t + np.array([0.0, 1.0, 2.0]))

    return omega_at


@dataclass(frozen=True)
class ImuFaults:
    """Injected faults. Probabilities are per byte (flip, drop) or per frame (garbage)."""

    flip: float = 0.0
    drop: float = 0.0
    garbage: float = 0.0
    pause_at_s: float | None = None
    pause_s: float = 0.0
    unplug_at_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("flip", "drop", "garbage"):
            p = getattr(self, name)
            if not 0.0 <= p <= 0.5:
                raise RigConfigError(f"fault probability {name}={p} must be in [0, 0.5]")
        if self.pause_s < 0:
            raise RigConfigError("pause_s must be non-negative")


@dataclass(frozen=True)
class VirtualImuConfig:
    """What the virtual board does. ``realtime=False`` sends as fast as the reader reads
    (deterministic, for tests); ``n_samples`` stops the stream after that many samples.
    Sample k is taken at simulation time ``k / rate_hz`` s after ``origin_ns`` on the host
    clock (default: when streaming starts); its device stamp is ``t0_us`` plus that time
    stretched by ``drift_ppm``."""

    rate_hz: float = 1000.0
    protocol: str = "binary"
    accel: bool = True
    counter_start: int = 0
    t0_us: int = 0
    drift_ppm: float = 0.0
    noise_radps: float = 0.0
    seed: int = 0
    realtime: bool = True
    n_samples: int | None = None
    faults: ImuFaults = field(default_factory=ImuFaults)
    origin_ns: int | None = None  # host time of sample 0 (share it with a VirtualCamera)

    def __post_init__(self) -> None:
        if not 1.0 <= self.rate_hz <= 10_000.0:
            raise RigConfigError(f"rate_hz={self.rate_hz} outside [1, 10000]")
        if self.protocol not in ("binary", "ascii"):
            raise RigConfigError(f"protocol={self.protocol!r} must be binary or ascii")
        if self.n_samples is not None and self.n_samples < 0:
            raise RigConfigError("n_samples must be non-negative")
        if abs(self.drift_ppm) > 10_000 or self.noise_radps < 0:
            raise RigConfigError("drift_ppm must be within +-1e4 and noise_radps non-negative")


class VirtualImu:
    """The virtual board. ``start()`` returns the slave path; ``stop()`` ends it.

    Truth log after (or during) the run: ``sent_index`` (sample numbers k), ``sent_counter``,
    ``sent_t_us`` (wrapped, as on the wire), ``sent_gyro_radps`` (exactly the values a
    decoder yields), ``damaged`` (sample numbers whose frames were altered by flips or drops).
    """

    def __init__(
        self, omega_at: MotionFn, config: VirtualImuConfig | None = None, clock: Clock | None = None
    ) -> None:
        self.omega_at = omega_at
        self.config = config or VirtualImuConfig()
        self.clock = clock or MonotonicClock()
        self._rng = np.random.default_rng(self.config.seed)
        self._stop = threading.Event()
        self.finished = threading.Event()  # n_samples sent, or unplugged
        self.unplugged = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = -1
        self._slave = -1
        self.port_path = ""
        self._lock = threading.Lock()
        self._index: list[np.ndarray] = []
        self._gyro: list[np.ndarray] = []
        self._t_us: list[np.ndarray] = []
        self.damaged: set[int] = set()
        self.error: BaseException | None = None
        self.bytes_sent = 0
        self.pauses = 0

    # ----------------------------------------------------------------- truth log
    @property
    def sent_index(self) -> np.ndarray:
        with self._lock:
            return np.concatenate(self._index) if self._index else np.zeros(0, np.int64)

    @property
    def sent_counter(self) -> np.ndarray:
        return (self.sent_index + self.config.counter_start) % COUNTER_MODULUS

    @property
    def sent_t_us(self) -> np.ndarray:
        with self._lock:
            return np.concatenate(self._t_us) if self._t_us else np.zeros(0, np.int64)

    @property
    def sent_gyro_radps(self) -> np.ndarray:
        with self._lock:
            return np.concatenate(self._gyro) if self._gyro else np.zeros((0, 3))

    # ----------------------------------------------------------------- lifecycle
    def open_pty(self) -> str:
        """Create the pseudo-terminal (raw mode) and return the slave path; idempotent.

        Open the port before :meth:`start`: pyserial flushes the input queue when it opens a
        port, so bytes sent earlier would be lost, as they would be on a real board."""
        if self._master < 0 and not self.port_path:
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)
            tty.setraw(self._master)
            os.set_blocking(self._master, False)
            self.port_path = os.ttyname(self._slave)
        return self.port_path

    def start(self) -> str:
        """Start streaming (opening the pty if needed); return the slave path."""
        if self._thread is not None:
            raise DeviceError("virtual IMU already started")
        path = self.open_pty()
        self._thread = threading.Thread(target=self._run, name="virtual-imu", daemon=True)
        self._thread.start()
        return path

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._close_master()
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1

    # ----------------------------------------------------------------- StreamEnd (rigs.imu)
    @property
    def finite(self) -> bool:
        """True when the board stops by itself (a sample limit), so a reader waits for its end."""
        return self.config.n_samples is not None

    def drained(self, bytes_decoded: int) -> bool:
        """True once the board has sent everything (or was unplugged) and ``bytes_decoded`` of
        what it sent reached the decoder."""
        if not self.finished.is_set():
            return False
        return self.unplugged.is_set() or bytes_decoded >= self.bytes_sent

    def close(self) -> None:
        self.stop()

    def unplug(self) -> None:
        """Pull the cable now: the reader sees the port vanish."""
        self._close_master()
        self.unplugged.set()
        self.finished.set()

    def _close_master(self) -> None:
        with self._lock:
            if self._master >= 0:
                os.close(self._master)
                self._master = -1

    # ----------------------------------------------------------------- generation
    def _samples(self, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        cfg = self.config
        k = np.arange(k0, k1, dtype=np.int64)
        t_s = k / cfg.rate_hz
        stretched_us = k * (1e6 / cfg.rate_hz) * (1.0 + cfg.drift_ppm * 1e-6)
        t_us = cfg.t0_us + np.rint(stretched_us).astype(np.int64)  # nearest microsecond
        omega = np.asarray(self.omega_at(t_s), dtype=float).reshape(k.size, 3)
        if cfg.noise_radps > 0:
            omega = omega + self._rng.normal(0.0, cfg.noise_radps, omega.shape)
        if cfg.protocol == "binary":
            counts = np.rint(omega / GYRO_SCALE_RADPS).astype(np.int64)
            gyro = counts * GYRO_SCALE_RADPS
        else:
            counts = np.zeros((k.size, 3), np.int64)
            gyro = omega
        return k, t_us, counts, gyro

    def _encode(
        self, k: np.ndarray, t_us: np.ndarray, counts: np.ndarray, gyro: np.ndarray
    ) -> bytes:
        cfg = self.config
        accel_counts = (0, 0, round(GRAVITY_MPS2 / ACCEL_SCALE_MPS2)) if cfg.accel else None
        accel = (0.0, 0.0, GRAVITY_MPS2) if cfg.accel else None
        out = bytearray()
        f = cfg.faults
        for i in range(k.size):
            if cfg.protocol == "binary":
                frame = bytearray(
                    encode_binary(
                        int(k[i]) + cfg.counter_start, int(t_us[i]), tuple(counts[i]), accel_counts
                    )
                )
            else:
                frame = bytearray(encode_ascii(int(t_us[i]), tuple(gyro[i]), accel))
            damaged = False
            if f.flip > 0:
                for pos in np.flatnonzero(self._rng.random(len(frame)) < f.flip):
                    frame[pos] ^= 1 << int(self._rng.integers(0, 8))
                    damaged = True
            if f.drop > 0:
                lost = np.flatnonzero(self._rng.random(len(frame)) < f.drop)
                for pos in lost[::-1]:
                    del frame[pos]
                damaged = damaged or lost.size > 0
            if f.garbage > 0 and self._rng.random() < f.garbage:
                n = int(self._rng.integers(1, 17))
                out += self._rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            if damaged:
                self.damaged.add(int(k[i]))
            out += frame
        return bytes(out)

    def _write_all(self, data: bytes) -> bool:
        """Write everything (the reader sets the pace); False if stopped or unplugged."""
        view = memoryview(data)
        while view:
            if self._stop.is_set() or self._master < 0:
                return False
            _, writable, _ = select.select([], [self._master], [], 0.05)
            if not writable:
                continue
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                continue
            except OSError:
                return False
            view = view[n:]
            self.bytes_sent += n
        return True

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # reported through .error, the thread must not die silently
            self.error = exc
        finally:
            self.finished.set()

    def _loop(self) -> None:
        cfg = self.config
        start_ns = self.clock.now_ns() if cfg.origin_ns is None else cfg.origin_ns
        k = 0
        paused = False
        while not self._stop.is_set():
            if cfg.n_samples is not None and k >= cfg.n_samples:
                self.finished.set()
                self._stop.wait(0.05)
                continue
            if cfg.realtime:
                due = int((self.clock.now_ns() - start_ns) * cfg.rate_hz // 1_000_000_000) + 1
            else:
                due = k + _BATCH
            if cfg.n_samples is not None:
                due = min(due, cfg.n_samples)
            f = cfg.faults
            if f.unplug_at_s is not None:
                due = min(due, int(np.ceil(f.unplug_at_s * cfg.rate_hz)))
            if due <= k:
                if f.unplug_at_s is not None and k >= f.unplug_at_s * cfg.rate_hz:
                    self.unplug()
                    return
                self._stop.wait(0.002)
                continue
            if (
                cfg.realtime
                and not paused
                and f.pause_at_s is not None
                and (due / cfg.rate_hz >= f.pause_at_s)
            ):
                paused = True
                self.pauses += 1
                self._stop.wait(f.pause_s)  # the board stalls; its samples come out late
            idx, t_us, counts, gyro = self._samples(k, due)
            data = self._encode(idx, t_us, counts, gyro)
            with self._lock:
                self._index.append(idx)
                self._t_us.append(t_us % (1 << 32))
                self._gyro.append(gyro)
            if not self._write_all(data):
                return
            k = due
