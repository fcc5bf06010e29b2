"""Work on consecutive frame pairs ``(f, f + 1)`` of a video, on all usable cores, in order.

Threads, not processes: OpenCV's decoding, corner detection and Lucas–Kanade release the GIL,
so two threads use two cores without pickling frames between processes (a 720p gray frame is
0.9 MB; a process pool would copy each one twice). Frames are read in blocks, each frame once
(the next block's while the last pairs of a block finish, so no core waits at a block's end),
so memory stays at about two blocks of frames however long the video is. The
results are those of a plain loop, in the same order: each pair's work depends only on its
two frames.
"""

from __future__ import annotations

import itertools
import os
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import numpy as np

T = TypeVar("T")
R = TypeVar("R")

#: Frame pairs handled per block (frames held in memory: about ``BLOCK + 1``).
BLOCK = 16


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def concurrently(calls: Sequence[Callable[[], T]], workers: int | None = None) -> list[T]:
    """``[c() for c in calls]`` with the calls on up to ``workers`` threads (default:
    :func:`usable_cores`): for work on large arrays, which numpy and OpenCV do without the GIL.

    >>> concurrently([lambda: 1, lambda: 2])
    [1, 2]
    """
    n = min(len(calls), workers if workers is not None else usable_cores())
    if n <= 1:
        return [c() for c in calls]
    with ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(lambda c: c(), calls))


def map_pairs(
    fn: Callable[[int, np.ndarray, np.ndarray], T],
    read_frame: Callable[[int], np.ndarray],
    firsts: Sequence[int],
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[T]:
    """``[fn(f, read_frame(f), read_frame(f + 1)) for f in firsts]`` (``firsts`` ascending),
    with the reads and calls spread over ``workers`` threads (default: :func:`usable_cores`).

    ``read_frame`` and ``fn`` are called from several threads at once; each frame is read
    once, a block of :data:`BLOCK` pairs ahead at most. ``progress(done, total)`` is called
    after each block.

    >>> frames = [np.full((2, 2), i) for i in range(4)]
    >>> map_pairs(lambda f, a, b: int(b[0, 0] - a[0, 0]) * f, frames.__getitem__, [0, 1, 2])
    [0, 1, 2]
    """
    firsts = [int(f) for f in firsts]
    if any(b <= a for a, b in itertools.pairwise(firsts)):
        raise ValueError("frame pairs must be given in ascending order of their first frame")
    n = workers if workers is not None else usable_cores()
    if n < 1:
        raise ValueError(f"workers must be at least 1, got {n}")
    blocks = [firsts[s : s + BLOCK] for s in range(0, len(firsts), BLOCK)]
    out: list[T] = []
    reads: dict[int, Future[np.ndarray]] = {}
    with ThreadPoolExecutor(max_workers=n) as pool:

        def prefetch(k: int) -> None:
            if k < len(blocks):
                for i in _frames_of(blocks[k]):
                    if i not in reads:
                        reads[i] = pool.submit(read_frame, i)

        try:
            prefetch(0)
            for k, block in enumerate(blocks):
                held = {i: reads[i].result() for i in _frames_of(block)}
                jobs = [pool.submit(fn, f, held[f], held[f + 1]) for f in block]
                # the next block's frames are read while this block's last pairs finish
                prefetch(k + 1)
                out.extend(j.result() for j in jobs)
                later = set(_frames_of(blocks[k + 1])) if k + 1 < len(blocks) else set()
                reads = {i: r for i, r in reads.items() if i in later}
                if progress is not None:
                    progress(len(out), len(firsts))
        except BaseException:
            pool.shutdown(cancel_futures=True)
            raise
    return out


def _frames_of(block: Sequence[int]) -> list[int]:
    return sorted(set(block) | {f + 1 for f in block})


def in_order(fn: Callable[[T], R], items: Sequence[T], workers: int) -> Iterator[R]:
    """``fn(item)`` of each item, in order, computed on up to ``workers`` threads with at most
    ``2 · workers`` results waiting (decoding and PNG encoding release the GIL: an import's
    frames are encoded two at a time on two cores, and memory stays bounded)."""
    if workers <= 1:
        yield from (fn(i) for i in items)
        return
    with ThreadPoolExecutor(workers) as pool:
        window: deque[Future[R]] = deque()
        for item in items:
            window.append(pool.submit(fn, item))
            if len(window) >= 2 * workers:
                yield window.popleft().result()
        while window:
            yield window.popleft().result()
