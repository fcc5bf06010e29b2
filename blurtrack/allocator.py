"""Allocator tuning for frame-rate detection (glibc only; elsewhere a no-op).

Detection allocates several full-frame arrays per frame (a 1280x720 float32 array is 3.6 MB).
glibc serves such blocks from the heap once one has been freed, but returns the heap's free
top to the kernel whenever it exceeds a threshold that is derived from the block size; the
next frame then page-faults all of that memory back in (measured: ~2300 faults, several ms per
1280x720 frame, a large part of the frame budget). Fixing both thresholds keeps freed frame
buffers in the process for reuse. The cost is that up to ``trim_bytes`` of freed memory may
stay mapped. This changes process-wide allocator settings, hence one explicit function that
detection calls once.
"""

from __future__ import annotations

import ctypes
import sys

#: glibc ``mallopt`` parameter numbers (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: Largest mmap threshold glibc accepts on 64-bit systems.
_MMAP_MAX_BYTES = 32 * 1024 * 1024

_state: dict[str, bool] = {}


def keep_frame_buffers(trim_bytes: int = 256 * 1024 * 1024) -> bool:
    """Make glibc keep freed full-frame buffers (blocks below 32 MB come from the heap, and
    at most ``trim_bytes`` of free heap top stays mapped). Idempotent; returns whether the
    settings are in effect (False where the C library has no ``mallopt``, e.g. not Linux)."""
    if "done" in _state:
        return _state["done"]
    ok = False
    if sys.platform.startswith("linux"):
        try:
            mallopt = ctypes.CDLL(None).mallopt
        except (OSError, AttributeError):
            mallopt = None
        if mallopt is not None:
            mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            mallopt.restype = ctypes.c_int
            ok = (
                mallopt(_M_MMAP_THRESHOLD, _MMAP_MAX_BYTES) == 1
                and mallopt(_M_TRIM_THRESHOLD, int(trim_bytes)) == 1
            )
    _state["done"] = ok
    return ok
