"""A function over a list of items in forked worker processes, the results in order.

The workers are forked, so they inherit everything the function needs (the loaded session,
the frames found so far, the blur model): nothing is pickled but the items and the results.
The function itself may be a closure; it is handed to the workers through a module-level
dict set before the pool forks. Where the platform cannot fork, or for one worker or item,
the items are processed in this process: the results do not depend on the worker count.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing as mp
import platform
from collections.abc import Callable, Iterable, Iterator, Sequence
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


def _call(task: tuple[bool, Any]) -> Any:
    is_job, what = task
    return _WORKER_STATE["jobs"][what]() if is_job else _WORKER_STATE["fn"](what)


class Jobs:
    """Side work for a :func:`fork_map`'s pool: functions of no argument (closures too, as the
    mapped function) computed in the workers before the items, a core's worth of this process's
    work that would otherwise hold up the map (the cues of the frames while the template pass
    gates them); ``results``, in their order, once the map has yielded its first item (or
    ended). Without workers they run in this process, after ``meanwhile``: the same values.
    """

    def __init__(self, fns: Iterable[Callable[[], Any]]) -> None:
        self.fns: list[Callable[[], Any]] = list(fns)
        self.results: list[Any] = []


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


#: OpenBLAS's thread-count functions under the names its builds export (numpy's and scipy's
#: wheels: ``scipy_openblas``, 64-bit integers; a plain OpenBLAS), getter and setter.
_OPENBLAS_THREADS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)


def _openblas() -> tuple[Any, Any] | None:
    """The loaded OpenBLAS's thread-count getter and setter, or None (another BLAS, not
    Linux, or none loaded yet)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = {ln.split()[-1] for ln in fh if "openblas" in ln and ".so" in ln}
    except OSError:
        return None
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get, put in _OPENBLAS_THREADS:
            if hasattr(lib, get) and hasattr(lib, put):
                return getattr(lib, get), getattr(lib, put)
    return None


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """OpenBLAS on one thread within the block (this process and the workers it forks), as
    it was after. Detection keeps every core busy with its own processes: a BLAS call that
    spreads over the cores too waits, spinning, for cores that are busy (dense, 150 frames:
    ~0.7 s of CPU over the command's ~13). Only speed depends on this, never a result (the
    tables are byte-identical)."""
    fns = _openblas()
    if fns is None:
        yield
        return
    get, put = fns
    before = int(get())
    put(1)
    try:
        yield
    finally:
        put(before)


def can_fork() -> bool:
    """Whether worker processes can be forked here."""
    return "fork" in mp.get_all_start_methods()


def fork_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int,
    chunk: int = 1,
    meanwhile: Callable[[], None] | None = None,
    jobs: Jobs | None = None,
) -> Iterator[R]:
    """``fn(item)`` for every item, in order, computed in ``workers`` forked processes.

    ``chunk``: items a worker takes at a time (larger for many cheap items). ``meanwhile``:
    work of this process that does not need the results, run while the workers compute
    (before the first item without workers). ``jobs``: side work computed in the pool ahead
    of the items (:class:`Jobs`). One map at a time (the state is module-level).
    """
    if workers < 1:
        raise DetectionError(f"workers must be >= 1, got {workers}")
    side = jobs.fns if jobs is not None else []
    n = min(workers, len(items) + len(side))
    if n <= 1 or not can_fork():
        if meanwhile is not None:
            meanwhile()
        if jobs is not None:
            jobs.results = [job() for job in side]
        for item in items:
            yield fn(item)
        return
    if _WORKER_STATE:
        raise DetectionError("fork_map: another map is already running in this process")
    _WORKER_STATE["fn"] = fn
    _WORKER_STATE["jobs"] = side
    try:
        ctx = mp.get_context("fork")
        init = worker_initializer(_worker_start)  # workers end when this process dies
        tasks = [(True, j) for j in range(len(side))] + [(False, item) for item in items]
        with ProcessPoolExecutor(n, mp_context=ctx, initializer=init) as pool:
            results = pool.map(_call, tasks, chunksize=chunk)  # submits every task (forks)
            if meanwhile is not None:
                meanwhile()
            if jobs is not None:
                jobs.results = [next(results) for _ in side]
            yield from results
    finally:
        _WORKER_STATE.clear()


def fork_call(fn: Callable[[], R], fork: bool = True) -> Callable[[], R]:
    """``fn()`` computed in one forked process while this one goes on; returns the function
    that waits for its value (raising what ``fn`` raised). Where ``fork`` is false or the
    platform cannot fork, ``fn`` runs here at once: the same value. Side work of one stage
    that a serial stage would otherwise run after its own (the gyro's direction beside the
    session fit): a core otherwise idle."""
    if not fork or not can_fork():
        try:
            value = fn()
        except Exception as exc:
            error = exc

            def raise_it() -> R:
                raise error

            return raise_it
        return lambda: value
    ctx = mp.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    init = worker_initializer()  # the child ends when this process dies

    def child() -> None:
        init()
        try:
            out: tuple[bool, Any] = (True, fn())
        except Exception as exc:
            out = (False, exc)
        try:
            send.send(out)
        except Exception as exc:  # a value or an exception that does not pickle
            send.send((False, DetectionError(f"a forked computation's result: {exc}")))

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    send.close()

    def result() -> R:
        try:
            got = receive.recv()
        except EOFError:
            got = None
        finally:
            proc.join()
            receive.close()
        if got is None:
            raise DetectionError(
                f"a forked computation ended without its result (exit {proc.exitcode})"
            )
        ok, value = got
        if not ok:
            raise value
        return value  # type: ignore[no-any-return]

    return result


def batch_positions(weighted: Iterable[tuple[int, int]], most: int) -> list[list[int]]:
    """The positions of ``weighted`` ``(position, weight)`` pairs, in order, cut into
    batches whose weights sum to at most ``most`` (a heavier one alone): the frames of one
    model call each, for the gyro's batched predictions."""
    out: list[list[int]] = []
    count = 0
    for k, n in weighted:
        if not out or count + n > most:
            out.append([])
            count = 0
        out[-1].append(k)
        count += n
    return out
