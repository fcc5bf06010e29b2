"""Progress bars of the CLI (tqdm on stderr); library code only takes callbacks.

A bar is drawn only on a terminal, never with ``--quiet``, and only once the work has run for
:data:`DELAY_S` seconds, so quick commands and logs stay clean.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any

#: Seconds of work before a bar appears.
DELAY_S = 2.0


def enabled(quiet: bool = False) -> bool:
    """Whether progress bars are drawn: stderr is a terminal and ``--quiet`` was not given."""
    return not quiet and sys.stderr.isatty()


class Progress:
    """``(done, total)`` callback that drives a tqdm bar (with ETA), created on first use.

    Use as a context manager so the bar is closed (and an error message printed after it
    starts on a fresh line); ``label`` updates the bar's description.
    """

    def __init__(self, desc: str, unit: str = "it", quiet: bool = False) -> None:
        self.desc = desc
        self.unit = unit
        self.on = enabled(quiet)
        self._bar: Any = None

    def __call__(self, done: int, total: int, label: str | None = None) -> None:
        if not self.on:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                desc=self.desc,
                unit=self.unit,
                delay=DELAY_S,
                dynamic_ncols=True,
                file=sys.stderr,
            )
        if label is not None:
            self._bar.set_postfix_str(label, refresh=False)
        if total != self._bar.total:
            self._bar.total = total
        self._bar.update(done - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def add_quiet_arg(p: Any) -> None:
    """``--quiet``: no progress bars (they are also off when stderr is not a terminal)."""
    p.add_argument(
        "--quiet", action="store_true", help="no progress bar (off anyway when not a terminal)"
    )
