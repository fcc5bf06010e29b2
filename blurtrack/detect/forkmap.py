"""A function over a list of items in forked worker processes, the results in order.

The workers are forked, so they inherit everything the function needs (the loaded session,
the frames found so far, the blur model): nothing is pickled but the items and the results.
The function itself may be a closure; it is handed to the workers through a module-level
dict set before the pool forks. Where the platform cannot fork, or for one worker or item,
the items are processed in this process: the results do not depend on the worker count.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import platform
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

from blurtrack.errors import DetectionError
from blurtrack.workers import worker_initializer

T = TypeVar("T")
R = TypeVar("R")

#: What a forked worker runs (set before the pool forks; never pickled).
_WORKER_STATE: dict[str, Any] = {}

#: glibc's ``mallopt`` parameter for the slack kept at the top of the heap, and the slack a
#: worker keeps (bytes).
_M_TOP_PAD = -2
WORKER_TOP_PAD = 64 << 20


def _call(item: Any) -> Any:
    return _WORKER_STATE["fn"](item)


def _worker_start() -> None:
    """A worker's heap keeps :data:`WORKER_TOP_PAD` of slack (glibc only; elsewhere nothing).

    A worker forked from a process that has loaded a session allocates its temporaries (frame
    images, templates) above the inherited heap; glibc returns the heap's freed top to the
    system at every free and faults it in again at the next frame (the template pass on 100
    dense frames: 750 000 page faults, 1.2 s of system time in the workers, its CPU 1.5x that
    of one process). Only speed depends on this, never a result.
    """
    if platform.libc_ver()[0] != "glibc":
        return
    ctypes.CDLL(None).mallopt(_M_TOP_PAD, WORKER_TOP_PAD)


def can_fork() -> bool:
    """Whether worker processes can be forked here."""
    return "fork" in mp.get_all_start_methods()


def fork_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int,
    chunk: int = 1,
    meanwhile: Callable[[], None] | None = None,
) -> Iterator[R]:
    """``fn(item)`` for every item, in order, computed in ``workers`` forked processes.

    ``chunk``: items a worker takes at a time (larger for many cheap items). ``meanwhile``:
    work of this process that does not need the results, run while the workers compute
    (before the first item without workers). One map at a time (the state is module-level).
    """
    if workers < 1:
        raise DetectionError(f"workers must be >= 1, got {workers}")
    n = min(workers, len(items))
    if n <= 1 or not can_fork():
        if meanwhile is not None:
            meanwhile()
        for item in items:
            yield fn(item)
        return
    if _WORKER_STATE:
        raise DetectionError("fork_map: another map is already running in this process")
    _WORKER_STATE["fn"] = fn
    try:
        ctx = mp.get_context("fork")
        init = worker_initializer(_worker_start)  # workers end when this process dies
        with ProcessPoolExecutor(n, mp_context=ctx, initializer=init) as pool:
            results = pool.map(_call, items, chunksize=chunk)  # submits every item (forks)
            if meanwhile is not None:
                meanwhile()
            yield from results
    finally:
        _WORKER_STATE.clear()
