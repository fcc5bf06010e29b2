"""Dataset builds on a Dask cluster (``blurtrack synth --cluster local:N | tcp://HOST:PORT``).

One task per triplet index. A worker renders the triplet (the same :class:`Renderer` as
``--workers``, so the bytes are those of a single-process build) and returns the encoded files
to the client, which writes them with the same atomic writer and appends the manifest line: no
shared file system is needed for the output. With ``shared_fs`` the workers write the files
into the dataset folder themselves (it must be mounted at the same path on every worker) and
return only the manifest record.

The client holds the dataset lock and the manifest, so a build interrupted anywhere resumes:
a dead worker's tasks are rerun by the scheduler on the others (a triplet depends only on the
spec and its index), and a dead client leaves only finished triplets under final names, which
the next run skips. At most a window of tasks is in flight (twice the workers' threads, and
for results returned to the client at most about :data:`RESULT_BUDGET_BYTES` of them), so
memory stays bounded on any cluster size.

Workers read the inputs (photos, gyro source) at the paths of the spec. Before the first task
every connected worker makes its renderer and checks them (:func:`prepare_worker`, a worker
that joins later does so on its first task): the image list and gyro data must give the
client's identity hash, else the build stops with one line naming the worker and what it
lacks, before any triplet is built.

A Dask worker is not a plain process: the nanny sets ``MALLOC_TRIM_THRESHOLD_``, which turns
off glibc's adaptive mmap threshold, so every large NumPy buffer of a render is a fresh mmap
whose pages fault in anew (ten times the page faults of ``--workers``, about 0.1 CPU s more
per 1280x720 triplet); and its profiler and 20 ms event-loop ticks cost about 4 % of a core
per process even when idle. Local clusters start without them (:data:`LOCAL_CONFIG`); on any
worker :func:`plain_malloc` restores the adaptive thresholds' end state. The local cluster
starts on a thread while the client reads the inputs and the manifest. ``dask.distributed``
is imported only here and only when a cluster build runs.
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import os
import re
import secrets
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from itertools import islice
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError, SynthesisError
from blurtrack.io.yamlio import read_yaml
from blurtrack.synth.dataset import (
    DEFAULT_PNG_LEVEL,
    MAX_WORKERS,
    Renderer,
    check_png_level,
    write_files,
)
from blurtrack.synth.images import list_images
from blurtrack.synth.run import BuildResult, BuildRun, inputs_identity, open_build
from blurtrack.synth.spec import DatasetSpec, Job
from blurtrack.synth.store import remove_temporaries

_LOCAL = re.compile(r"local:([0-9]{1,4})")
_REMOTE = re.compile(r"(tcp|tls)://[A-Za-z0-9.\-\[\]:]+:[0-9]{1,5}")
#: Default seconds to wait for the scheduler and for its first worker.
CONNECT_TIMEOUT_S = 10.0
#: Results in flight when workers return files to the client (bytes, estimated).
RESULT_BUDGET_BYTES = 2 * 1024**3
#: Dask settings of ``local:N`` clusters: worker processes as plain as ``--workers`` (glibc's
#: own malloc thresholds; no statistical profiler) and slower housekeeping ticks.
LOCAL_CONFIG: dict[str, Any] = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "500ms",
    "distributed.admin.system-monitor.interval": "2s",
}
#: glibc ``mallopt`` parameters (``malloc.h``) and where its adaptive mmap threshold stops
#: rising on 64-bit (``DEFAULT_MMAP_THRESHOLD_MAX``); the trim threshold follows at twice it.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD_MAX = 32 * 1024**2


def parse_cluster(text: str) -> tuple[str, Any]:
    """``"local:N"`` -> ``("local", N)``; ``"tcp://HOST:PORT"`` -> ``("remote", text)``."""
    m = _LOCAL.fullmatch(text)
    if m:
        n = int(m.group(1))
        if not 1 <= n <= MAX_WORKERS:
            raise SynthesisError(f"--cluster local:N needs 1 <= N <= {MAX_WORKERS}, got {text!r}")
        return "local", n
    if _REMOTE.fullmatch(text):
        return "remote", text
    raise SynthesisError(f"--cluster must be local:N or tcp://HOST:PORT, got {text!r}")


# ------------------------------------------------------------------ worker side
_RENDERERS: dict[tuple[str, int], Renderer] = {}
_RENDERERS_LOCK = threading.Lock()


def _where(worker: Any = None) -> str:
    """This worker's address and host (``worker``: a ``distributed.Worker`` where no task
    runs)."""
    try:
        from distributed import get_worker

        address = worker.address if worker is not None else get_worker().address
        return f"{address} ({socket.gethostname()})"
    except (ImportError, ValueError):
        return socket.gethostname()


def plain_malloc() -> bool:
    """In a process started with ``MALLOC_TRIM_THRESHOLD_`` (a Dask nanny's worker), set
    glibc's mmap and trim thresholds to where its adaptive thresholds settle in a plain
    process, so that freed render buffers are reused instead of unmapped; True if changed.
    Elsewhere (no such variable, not glibc) it does nothing."""
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX) == 1
    return mallopt(_M_TRIM_THRESHOLD, 2 * _MMAP_THRESHOLD_MAX) == 1 and ok


def worker_renderer(
    spec_dict: dict[str, Any], identity: str, png_level: int, out: str | None, worker: Any = None
) -> Renderer:
    """This worker's renderer for the dataset ``identity``, made (and its inputs checked
    against the identity) on first use; ``out``: the dataset folder a shared-fs worker must
    see."""
    key = (identity, int(png_level))
    with _RENDERERS_LOCK:
        r = _RENDERERS.get(key)
        if r is not None:
            return r
        try:
            cv2.setNumThreads(1)
            plain_malloc()
            r = Renderer(spec_dict, png_level)
            images = list_images(r.spec.images)
            if inputs_identity(r.spec, images, r.source.fingerprint()) != identity:
                raise SynthesisError(
                    f"its photos under {r.spec.images} or its gyro data {r.spec.gyro} differ "
                    f"from the client's"
                )
            if out is not None:
                meta = Path(out) / "dataset.yaml"
                have = read_yaml(meta, "dataset.yaml") if meta.is_file() else None
                if not isinstance(have, dict) or have.get("identity") != identity:
                    raise SynthesisError(
                        f"it does not see the dataset folder {out} (--shared-fs needs it "
                        f"mounted at the same path on every worker)"
                    )
        except BlurTrackError as exc:
            raise SynthesisError(f"worker {_where(worker)} lacks the inputs: {exc}") from None
        _RENDERERS.clear()  # one dataset at a time per worker process
        _RENDERERS[key] = r
        return r


def prepare_worker(
    spec_dict: dict[str, Any],
    identity: str,
    png_level: int,
    out: str | None,
    dask_worker: Any = None,
) -> bool:
    """Make this worker's renderer and check its inputs (``Client.run`` on every worker
    before the build, which passes ``dask_worker``; :class:`SynthesisError` names what the
    worker lacks)."""
    worker_renderer(spec_dict, identity, png_level, out, dask_worker)
    return True


def render_task(
    spec_dict: dict[str, Any],
    identity: str,
    png_level: int,
    job: Job,
    out: str | None,
    tag: str,
) -> tuple[dict[str, Any], dict[str, bytes | np.ndarray] | None]:
    """One triplet on a worker: its manifest record and its files (``None`` once written to
    the shared ``out``)."""
    r = worker_renderer(spec_dict, identity, png_level, out)
    try:
        rec, files = r.render(job)
    except BlurTrackError as exc:
        raise SynthesisError(f"worker {_where()}: {exc}") from None
    if out is None:
        return rec, files
    write_files(Path(out), files, tag)
    return rec, None


# ------------------------------------------------------------------ client side
def _local_cluster(n: int) -> Any:
    """A ``LocalCluster`` of ``n`` single-threaded worker processes on 127.0.0.1."""
    import logging

    import dask
    from distributed import LocalCluster

    with dask.config.set(LOCAL_CONFIG):  # read by the scheduler and nannies it starts
        # The nannies pass their config to the workers they (re)start, but merged shallowly
        # over the global one: give them their own copy, or a restarted worker would get the
        # defaults back once this block ends.
        config = {"distributed": copy.deepcopy(dask.config.get("distributed"))}
        return LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.CRITICAL,  # task errors reach the client as exceptions
            config=config,
        )


class LocalStart:
    """A ``local:N`` cluster started on a thread, so that its worker processes start while
    the client reads the inputs and the manifest; :meth:`close` stops it."""

    def __init__(self, n: int) -> None:
        self._got: list[Any] = []
        self._closed = False
        self._thread = threading.Thread(
            target=self._start, args=(n,), name="blurtrack-local-cluster", daemon=True
        )
        self._thread.start()

    def _start(self, n: int) -> None:
        try:
            self._got.append(_local_cluster(n))
        except BaseException as exc:  # re-raised by get() in the caller's thread
            self._got.append(exc)

    def get(self) -> Any:
        self._thread.join()
        got = self._got[0]
        if isinstance(got, BaseException):
            raise got
        return got

    def close(self) -> None:
        self._thread.join()
        if not self._closed and self._got and not isinstance(self._got[0], BaseException):
            self._closed = True
            self._got[0].close()


@contextlib.contextmanager
def connect(
    cluster: str, timeout_s: float = CONNECT_TIMEOUT_S, local: LocalStart | None = None
) -> Iterator[Any]:
    """A ``distributed.Client`` on a fresh ``LocalCluster`` (``local:N``: N single-threaded
    worker processes on 127.0.0.1; ``local``: one already starting) or on a running
    scheduler, with at least one worker."""
    kind, value = parse_cluster(cluster)
    try:
        from distributed import Client
    except ImportError:
        raise SynthesisError(
            "--cluster needs dask.distributed: pip install 'blurtrack[cluster]'"
        ) from None
    with contextlib.ExitStack() as stack:
        if kind == "local":
            local = local or LocalStart(value)
            stack.callback(local.close)
            value = local.get()
        try:
            client = stack.enter_context(Client(value, timeout=timeout_s))
        except (OSError, TimeoutError) as exc:
            raise SynthesisError(
                f"cannot reach the dask scheduler at {cluster} within {timeout_s:g} s "
                f"({type(exc).__name__}); is `dask scheduler` running there?"
            ) from None
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError:
            raise SynthesisError(
                f"the dask scheduler at {cluster} has no workers (waited {timeout_s:g} s)"
            ) from None
        yield client


def check_workers(
    client: Any,
    cluster: str,
    spec_dict: dict[str, Any],
    identity: str,
    png_level: int,
    out: str | None,
) -> int:
    """Every connected worker makes its renderer and checks its inputs
    (:func:`prepare_worker`); the number of workers checked."""
    try:
        done = client.run(prepare_worker, spec_dict, identity, png_level, out)
    except (OSError, TimeoutError) as exc:
        raise SynthesisError(
            f"lost a worker of {cluster} while checking the inputs ({type(exc).__name__}); "
            f"rerun the same command"
        ) from None
    return len(done)


def _window(client: Any, per_task_bytes: int | None) -> int:
    threads = sum(client.nthreads().values())
    n = max(4, 2 * threads)
    if per_task_bytes:
        n = min(n, max(2, RESULT_BUDGET_BYTES // per_task_bytes))
    return n


def _run_tasks(client: Any, run: BuildRun, cluster: str, shared_fs: bool, png_level: int) -> None:
    from distributed import KilledWorker, as_completed

    spec_dict = run.spec.to_dict()
    W, H = run.spec.params.size
    per_task = None if shared_fs else W * H * (6 * 4 + 2 * 3 + (5 if run.spec.extras else 0))
    out = str(run.root.resolve()) if shared_fs else None
    jobs = iter(run.todo)
    run_id = secrets.token_hex(8)  # keys of this run only: two builds never share a task

    def submit(job: Job) -> Any:
        return client.submit(
            render_task,
            spec_dict,
            run.identity,
            png_level,
            job,
            out,
            run.tag,
            key=f"blurtrack-triplet-{run_id}-{job.index}",
            pure=False,
        )

    check_workers(client, cluster, spec_dict, run.identity, png_level, out)
    run.start()
    ac = as_completed(
        [submit(j) for j in islice(jobs, _window(client, per_task))], with_results=True
    )
    checked = time.monotonic()
    while True:
        item = _next_result(ac, cluster, KilledWorker)
        if item is None:
            return
        rec, files = item
        if files is not None:
            write_files(run.root, files, run.tag)
        run.record(rec)
        more = 1
        if time.monotonic() - checked > 2.0:  # workers may have joined: widen the window
            checked = time.monotonic()
            more += max(0, _window(client, per_task) - ac.count() - 1)
        for job in islice(jobs, more):
            ac.add(submit(job))


def _next_result(ac: Any, cluster: str, killed: type[BaseException]) -> Any:
    """The next finished task's result (``None`` when all are done), with the cluster's
    failures as one-line errors (a task's own error comes through as it was raised)."""
    from concurrent.futures import CancelledError

    try:
        return next(ac)[1]
    except StopIteration:
        return None
    except killed as exc:
        raise SynthesisError(
            f"task {getattr(exc, 'task', '?')} killed the workers that ran it several times "
            f"(out of memory?); rerun the same command to resume"
        ) from None
    except CancelledError:
        raise SynthesisError(
            f"the dask scheduler at {cluster} cancelled the build; rerun to resume"
        ) from None
    except (OSError, TimeoutError) as exc:  # CommClosedError is an OSError
        raise SynthesisError(
            f"lost the dask scheduler at {cluster} ({type(exc).__name__}); rerun the same "
            f"command to resume"
        ) from None


def build_on_cluster(
    spec: DatasetSpec,
    out: str | Path,
    cluster: str,
    shard: tuple[int, int] = (0, 1),
    shared_fs: bool = False,
    progress: Callable[[int, int], None] | None = None,
    png_level: int = DEFAULT_PNG_LEVEL,
    timeout_s: float = CONNECT_TIMEOUT_S,
) -> BuildResult:
    """Build (or resume) the triplets of ``shard`` on the Dask cluster ``cluster``; the files
    and manifest are those of :func:`blurtrack.synth.dataset.build`, byte for byte."""
    check_png_level(png_level)
    if not 0 < timeout_s <= 3600:
        raise SynthesisError(f"cluster timeout must be in (0, 3600] s, got {timeout_s}")
    kind, n = parse_cluster(cluster)
    local = LocalStart(n) if kind == "local" else None  # starts while the inputs are read
    try:
        with open_build(spec, out, shard, progress) as run:
            if not run.todo:
                run.start()
            else:
                try:
                    with connect(cluster, timeout_s, local) as client:
                        _run_tasks(client, run, cluster, shared_fs, png_level)
                finally:
                    if shared_fs:  # temporaries of workers that died mid-write
                        remove_temporaries(run.root, run.tag)
    finally:
        if local is not None:
            local.close()
    return run.result()
