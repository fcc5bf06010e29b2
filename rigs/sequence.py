"""Unwrapping of sample counters and device time, and counting of dropped samples.

The binary protocol's 16-bit counter wraps every 65536 samples (65.5 s at 1 kHz) and its 32-bit
microsecond clock every 71.6 minutes. :class:`Sequencer` turns both into monotonic int64 values
and counts the samples that never arrived (counter gaps). When the nominal rate is known, the
time step between two samples chooses among the counter deltas that differ by whole wraps, so
even a gap longer than a full counter period is counted right. ASCII lines have no counter; their
gaps are estimated from the time step and the nominal rate.

A frame can pass its CRC and still carry a wrong counter or time (firmware that fills the field
wrongly, a bit flipped before the CRC was computed). Once the rate is known (given, or estimated
from the first samples), every counter step is checked against the device-time step: a sample
whose two disagree is one *bad* sample, discarded, and never a jump of thousands of dropped
samples and counter wraps. A sample whose device time repeats the last kept one's is a
*duplicate* (a resend, or a device clock coarser than its sample period): it is discarded too,
because a second sample at one instant carries no timing and the session needs increasing times.
The counts always add up: ``received = kept + duplicates + bad_counter + time_jumps_back``, and
``dropped`` counts only counter slots for which nothing arrived at all.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from rigs.errors import RigConfigError
from rigs.protocol import COUNTER_MODULUS, TIME_MODULUS_US

#: Largest mismatch, in samples, between a counter step and the step the device time implies:
#: ``COUNTER_TOL_SAMPLES + rel * expected``. The absolute part rejects a counter that is off by
#: even one sample between neighbours. ``rel`` is COUNTER_TOL_NOMINAL (a nominal rate may be off
#: by several percent: a "1000 Hz" part running at 1024 Hz is 2.4 % off) until
#: MEASURED_AFTER samples have been kept, then COUNTER_TOL_MEASURED against the rate measured
#: on them (clock drift is below 0.1 %).
COUNTER_TOL_SAMPLES = 0.5
COUNTER_TOL_NOMINAL = 0.1
COUNTER_TOL_MEASURED = 0.01
MEASURED_AFTER = 16
#: After this many consecutive bad samples that agree with each other (each 1 to
#: REANCHOR_MAX_STEP counts after the one before, and later in device time), the last kept sample
#: is taken to be the wrong one (or the device restarted its counter) and the sequencer follows
#: the new counter, numbering it from the device time. Where the rate had not been measured yet,
#: the nominal rate may be what is wrong (``rate=`` mistyped): it is dropped, and counters are
#: trusted until the rate is measured on the samples kept.
REANCHOR_AFTER = 4
REANCHOR_MAX_STEP = 4


@dataclass
class SequenceStats:
    """Counter and clock bookkeeping of one stream (all counts are samples unless said).

    ``received = kept + duplicates + bad_counter + time_jumps_back`` at all times.
    """

    received: int = 0  # samples pushed (every decoded frame or line)
    kept: int = 0  # samples returned, with increasing index and device time
    dropped: int = 0  # counter slots (time slots for ASCII) for which nothing arrived
    gaps: int = 0  # number of places where samples went missing
    duplicates: int = 0  # device time equal to the last kept sample's (discarded)
    bad_counter: int = 0  # counter and device time disagree (discarded)
    counter_wraps: int = 0
    time_wraps: int = 0
    time_jumps_back: int = 0  # device time went backwards (device reset): sample discarded
    reanchors: int = 0  # times the sequencer gave up its last kept counter for a new one

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
    >>> s.push(4242, 4010) is None, s.push(3, 5010).index, s.stats.bad_counter, s.stats.dropped
    (True, 65539, 1, 1)
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
        self._sum_steps = 0  # counter steps between kept samples
        self._sum_dt_us = 0  # device time between kept samples, us
        self._filled = 0  # discarded samples since the last kept one that took a counter slot
        self._run: list[tuple[int, int]] = []  # consecutive bad (counter, t_us) that agree
        self._nominal_ok = True  # False once a re-anchor showed the nominal rate to be wrong

    def _estimated_rate(self) -> float | None:
        """Samples per second: the nominal rate, else the median single step (>= 16 seen)."""
        if self.rate_hz is not None and self._nominal_ok:
            return self.rate_hz
        if len(self._deltas_us) >= 16:
            deltas = sorted(self._deltas_us)
            median = deltas[len(deltas) // 2]
            return 1e6 / median if median > 0 else None
        return None

    def _check_rate(self) -> tuple[float | None, float]:
        """Rate (Hz) to judge counters by, and the relative tolerance that goes with it."""
        if self.stats.kept > MEASURED_AFTER and self._sum_dt_us > 0:
            return self._sum_steps * 1e6 / self._sum_dt_us, COUNTER_TOL_MEASURED
        return self._estimated_rate(), COUNTER_TOL_NOMINAL

    def _counter_step(self, step0: int, dt_us: int) -> tuple[int, bool]:
        """Unwrapped counter step from a raw step modulo 65536 and the device-time step (us);
        and whether the two agree (always True while the rate is unknown)."""
        rate, rel = self._check_rate()
        if rate is None:
            return step0, True
        expected = dt_us * rate / 1e6
        step = step0 + max(0, round((expected - step0) / COUNTER_MODULUS)) * COUNTER_MODULUS
        ok = abs(step - expected) <= COUNTER_TOL_SAMPLES + rel * expected
        return step, ok and step > 0

    def _bad(self, counter: int, t_us: int) -> bool:
        """Count one bad sample; True once enough agreeing bad samples say: follow them."""
        self.stats.bad_counter += 1
        self._filled += 1
        if self._run:
            c0, t0 = self._run[-1]
            dt = (t_us - t0) % TIME_MODULUS_US
            step0 = (counter - c0) % COUNTER_MODULUS
            if not (0 < dt < TIME_MODULUS_US // 2 and 1 <= step0 <= REANCHOR_MAX_STEP):
                self._run.clear()
        self._run.append((counter, t_us))
        return len(self._run) >= REANCHOR_AFTER

    def push(self, counter: int | None, t_us: int) -> Sequenced | None:
        """One sample's raw counter (None for ASCII) and device time (us, wrapping at 2**32)."""
        st = self.stats
        st.received += 1
        if self._last_t_raw is None:
            self._last_t_raw, self._last_counter = t_us, counter
            self._index = counter if counter is not None else 0
            self._t_unwrapped = t_us
            st.kept += 1
            return Sequenced(self._index, self._t_unwrapped)
        dt_us = (t_us - self._last_t_raw) % TIME_MODULUS_US
        if dt_us >= TIME_MODULUS_US // 2:
            st.time_jumps_back += 1
            return None
        if dt_us == 0:
            st.duplicates += 1
            if counter is not None and counter != self._last_counter:
                self._filled += 1  # a new sample with a stale time, not a resend
            return None
        rate = self._estimated_rate()
        reanchored = False
        if counter is None or self._last_counter is None:
            step = max(1, round(dt_us * rate / 1e6)) if rate is not None else 1
        else:
            step0 = (counter - self._last_counter) % COUNTER_MODULUS
            if rate is None and step0 == 0:
                st.duplicates += 1  # nothing to judge the time by yet: the counter decides
                return None
            step, ok = self._counter_step(step0, dt_us)
            if not ok:
                if not self._bad(counter, t_us):
                    return None
                # the kept counter was the wrong one: follow the new one, numbered by time
                st.bad_counter -= 1
                self._filled -= 1
                st.reanchors += 1
                reanchored = True
                if self._check_rate()[1] == COUNTER_TOL_NOMINAL:  # the rate was never measured
                    self._nominal_ok = False
                check_rate = self._check_rate()[0]
                by_time = round(dt_us * check_rate / 1e6) if check_rate is not None else step0
                step = max(1, by_time)
        self._run.clear()
        if len(self._deltas_us) < 64 and step == 1:
            self._deltas_us.append(dt_us)
        missing = step - 1 - self._filled
        if missing > 0:
            st.dropped += missing
            st.gaps += 1
        self._filled = 0
        if counter is not None and self._last_counter is not None:
            if reanchored:
                st.counter_wraps += int(counter < self._last_counter)
            else:
                st.counter_wraps += (self._last_counter + step) // COUNTER_MODULUS
        if t_us < self._last_t_raw:
            st.time_wraps += 1
        self._index += step
        self._t_unwrapped += dt_us
        self._sum_steps += step
        self._sum_dt_us += dt_us
        self._last_t_raw, self._last_counter = t_us, counter
        st.kept += 1
        return Sequenced(self._index, self._t_unwrapped)
