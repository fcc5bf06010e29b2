"""Clocks injected into drivers, simulated devices and the recorder.

Everything that needs "now" takes a :class:`Clock`, so that tests can drive time by hand
instead of sleeping. Host time is ``time.monotonic_ns`` (CLOCK_MONOTONIC on Linux, the clock
that V4L2 buffer timestamps use as well).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """Anything with ``now_ns() -> int`` (nanoseconds on a monotonic host timeline)."""

    def now_ns(self) -> int: ...


class MonotonicClock:
    """The host's monotonic clock, in nanoseconds."""

    def now_ns(self) -> int:
        return time.monotonic_ns()


class ManualClock:
    """A clock that only moves when told to (thread safe).

    >>> c = ManualClock(start_ns=5)
    >>> c.advance_s(0.5); c.now_ns()
    500000005
    """

    def __init__(self, start_ns: int = 0) -> None:
        self._now_ns = int(start_ns)
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._now_ns

    def advance_ns(self, delta_ns: int) -> None:
        if delta_ns < 0:
            raise ValueError("a clock cannot go backwards")
        with self._lock:
            self._now_ns += int(delta_ns)

    def advance_s(self, delta_s: float) -> None:
        self.advance_ns(round(delta_s * 1e9))
