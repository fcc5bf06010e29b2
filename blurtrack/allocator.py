"""The C allocator's settings for a ``blurtrack`` process (glibc only; elsewhere a no-op).

The commands work on arrays of a few to a few tens of megabytes that live for one step: a
1280x720 float32 frame is 3.6 MB, a natural calibration's patch stacks and Jacobians tens of
megabytes. glibc serves blocks above its dynamic mmap threshold with fresh ``mmap`` pages and
returns the heap's free top to the kernel beyond a threshold derived from the block sizes, so
the next such array faults all its pages in again: detection measured ~2300 faults, several ms
per 1280x720 frame; ``blurtrack calibrate`` on 10 s of 720p ~1 million faults and 5-9 s of
system CPU (docs/journal/natural.md, "Allocator settings"). :func:`keep_heap` fixes the mmap
threshold at glibc's 32 MiB maximum, keeps up to 1 GiB of free heap top mapped and grows the
heap 256 MiB at a time (address space only, until touched), so freed blocks are reused
(calibrate: ~0.2 million faults, 2-3.6 s). The price: a process keeps its peak heap until it
exits (calibrate's peak RSS 1.2 -> 1.4 GB). Results do not change, only where memory comes
from.

These are process-wide settings, hence one explicit, idempotent function: the ``blurtrack``
program calls it at start (:func:`blurtrack.cli.main`), detection in each worker process. The
user's own tuning (``MALLOC_*`` variables, ``glibc.malloc`` tunables) takes precedence. No
library exposes ``mallopt``, hence :mod:`ctypes`.
"""

from __future__ import annotations

import ctypes
import os
import sys

#: glibc ``mallopt`` parameter numbers (malloc.h) and the values :func:`keep_heap` sets.
M_TRIM_THRESHOLD = -1
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
SETTINGS: tuple[tuple[int, int], ...] = (
    (M_MMAP_THRESHOLD, 32 << 20),  # the largest glibc accepts on 64-bit systems
    (M_TRIM_THRESHOLD, 1 << 30),
    (M_TOP_PAD, 256 << 20),
)

_state: dict[str, bool] = {}


def user_tuned() -> bool:
    """Whether the environment sets glibc's allocator itself."""
    return any(k.startswith("MALLOC_") for k in os.environ) or (
        "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")
    )


def keep_heap() -> bool:
    """Apply :data:`SETTINGS` to this process's glibc ``malloc`` (once; later calls return
    the first's answer): whether they are in effect. ``False``, nothing changed, on other C
    libraries (musl has no ``gnu_get_libc_version``) or where :func:`user_tuned`."""
    if "done" not in _state:
        _state["done"] = _apply()
    return _state["done"]


def _apply() -> bool:
    if not sys.platform.startswith("linux") or user_tuned():
        return False
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # noqa: B018  # glibc only
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in SETTINGS)
