"""Unwrapping of sample counters and device time, and counting of dropped samples.

The binary protocol's 16-bit counter wraps every 65536 samples (65.5 s at 1 kHz) and its 32-bit
microsecond clock every 71.6 minutes. :class:`Sequencer` turns both into monotonic int64 values
and counts the samples that never arrived (counter gaps). When the nominal rate is known, the
time step between two samples chooses among the counter deltas that differ by whole wraps, so
even a gap longer than a full counter period is counted right. ASCII lines have no counter; their
gaps are estimated from the time step and the nominal rate.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from rigs.errors import RigConfigError
from rigs.protocol import COUNTER_MODULUS, TIME_MODULUS_US


@dataclass
class SequenceStats:
    """Counter and clock bookkeeping of one stream."""

    dropped: int = 0  # samples missing according to counter gaps (or time gaps for ASCII)
    gaps: int = 0  # number of places where samples went missing
    duplicates: int = 0  # samples whose counter did not advance (discarded)
    counter_wraps: int = 0
    time_wraps: int = 0
    time_jumps_back: int = 0  # device time went backwards (device reset): sample discarded

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(frozen=True)
class Sequenced:
    """Monotonic index and device time of an accepted sample."""

    index: int  # unwrapped counter (or estimated sample number for ASCII)
    t_dev_us: int  # unwrapped device time, microseconds


class Sequencer:
    """Feed (counter, t_us) pairs in arrival order; get unwrapped values or None (discarded).

    >>> s = Sequencer(rate_hz=1000.0)
    >>> [s.push(c, t) for c, t in [(65534, 10), (65535, 1010), (1, 3010)]][-1]
    Sequenced(index=65537, t_dev_us=3010)
    >>> s.stats.dropped, s.stats.counter_wraps
    (1, 1)
    """

    def __init__(self, rate_hz: float | None = None) -> None:
        if rate_hz is not None and not rate_hz > 0:
            raise RigConfigError("rate_hz must be positive")
        self.rate_hz = rate_hz
        self.stats = SequenceStats()
        self._last_counter: int | None = None
        self._last_t_raw: int | None = None
        self._index = 0
        self._t_unwrapped = 0
        self._deltas_us: list[int] = []

    def _estimated_rate(self) -> float | None:
        if self.rate_hz is not None:
            return self.rate_hz
        if len(self._deltas_us) >= 16:
            deltas = sorted(self._deltas_us)
            median = deltas[len(deltas) // 2]
            return 1e6 / median if median > 0 else None
        return None

    def push(self, counter: int | None, t_us: int) -> Sequenced | None:
        if self._last_t_raw is None:
            self._last_t_raw, self._last_counter = t_us, counter
            self._index = counter if counter is not None else 0
            self._t_unwrapped = t_us
            return Sequenced(self._index, self._t_unwrapped)
        dt_us = (t_us - self._last_t_raw) % TIME_MODULUS_US
        if dt_us >= TIME_MODULUS_US // 2:
            self.stats.time_jumps_back += 1
            return None
        rate = self._estimated_rate()
        if counter is None or self._last_counter is None:
            step = max(1, round(dt_us * rate / 1e6)) if rate is not None else 1
            if dt_us == 0:
                self.stats.duplicates += 1
                return None
        else:
            step = (counter - self._last_counter) % COUNTER_MODULUS
            if rate is not None:
                expected = dt_us * rate / 1e6
                wraps = round((expected - step) / COUNTER_MODULUS)
                step += max(0, wraps) * COUNTER_MODULUS
            if step == 0:
                self.stats.duplicates += 1
                return None
        if len(self._deltas_us) < 64 and step == 1:
            self._deltas_us.append(dt_us)
        if step > 1:
            self.stats.dropped += step - 1
            self.stats.gaps += 1
        if counter is not None:
            self.stats.counter_wraps += (self._index % COUNTER_MODULUS + step) // COUNTER_MODULUS
        if t_us < self._last_t_raw:
            self.stats.time_wraps += 1
        self._index += step
        self._t_unwrapped += dt_us
        self._last_t_raw, self._last_counter = t_us, counter
        return Sequenced(self._index, self._t_unwrapped)
