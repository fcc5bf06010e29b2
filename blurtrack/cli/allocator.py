"""The C allocator's settings for one ``blurtrack`` process (glibc only).

The commands work on arrays of a few to a few tens of megabytes that live for one step
(patch stacks, Jacobians, image batches). glibc's ``malloc`` serves such requests with fresh
``mmap`` pages (above its dynamic threshold, at most 32 MiB) and returns freed heap tops to
the kernel (``M_TRIM_THRESHOLD``), so the next array of that size faults its pages in again:
``blurtrack calibrate`` on 10 s of 720p video took ~1 million minor page faults and 6-8 s of
system time (docs/natural.md, "Allocator settings"). Keeping the heap instead (fixed mmap
threshold at its 32 MiB maximum, no trimming below 1 GiB, the heap grown 256 MiB at a time,
which only reserves address space) cuts that to ~0.2 million faults and 2-3 s. The price: the
process keeps its peak heap until it exits (``calibrate``: peak RSS 1.2 → 1.4 GB).

No library sets these (Python exposes no ``mallopt``), hence a few lines of :mod:`ctypes`. The
results of every command are unchanged: only where memory comes from differs.
"""

from __future__ import annotations

import ctypes
import os
import sys

#: ``mallopt`` parameters (glibc's ``malloc.h``) and the values set.
M_TRIM_THRESHOLD = -1
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
SETTINGS: tuple[tuple[int, int], ...] = (
    (M_MMAP_THRESHOLD, 32 << 20),
    (M_TRIM_THRESHOLD, 1 << 30),
    (M_TOP_PAD, 256 << 20),
)


def tune_allocator() -> bool:
    """Apply :data:`SETTINGS` to this process's glibc ``malloc``; ``False`` (nothing changed)
    on other C libraries, or where the user tuned glibc's allocator (``MALLOC_*`` variables or
    ``glibc.malloc`` tunables: theirs take precedence)."""
    if not sys.platform.startswith("linux"):
        return False
    if any(k.startswith("MALLOC_") for k in os.environ):
        return False
    if "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # noqa: B018  # glibc only (musl has no such symbol)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in SETTINGS)
