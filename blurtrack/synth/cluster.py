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

Workers read the inputs (photos, gyro source) at the paths of the spec. The first task on each
worker checks them: the image list and gyro data must give the client's identity hash, else
the build stops with one line naming the worker and what it lacks. ``dask.distributed`` is
imported only here and only when a cluster build runs.
"""

from __future__ import annotations

import contextlib
import re
import secrets
import socket
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
    BuildResult,
    BuildRun,
    DatasetSpec,
    Job,
    Renderer,
    check_png_level,
    inputs_identity,
    open_build,
    write_files,
)
from blurtrack.synth.images import list_images
from blurtrack.synth.store import remove_temporaries

_LOCAL = re.compile(r"local:([0-9]{1,4})")
_REMOTE = re.compile(r"(tcp|tls)://[A-Za-z0-9.\-\[\]:]+:[0-9]{1,5}")
#: Default seconds to wait for the scheduler and for its first worker.
CONNECT_TIMEOUT_S = 10.0
#: Results in flight when workers return files to the client (bytes, estimated).
RESULT_BUDGET_BYTES = 2 * 1024**3


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


def _where() -> str:
    try:
        from distributed import get_worker

        return f"{get_worker().address} ({socket.gethostname()})"
    except (ImportError, ValueError):
        return socket.gethostname()


def worker_renderer(
    spec_dict: dict[str, Any], identity: str, png_level: int, out: str | None
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
            raise SynthesisError(f"worker {_where()} lacks the inputs: {exc}") from None
        _RENDERERS.clear()  # one dataset at a time per worker process
        _RENDERERS[key] = r
        return r


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
@contextlib.contextmanager
def connect(cluster: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Iterator[Any]:
    """A ``distributed.Client`` on a fresh ``LocalCluster`` (``local:N``: N single-threaded
    worker processes on 127.0.0.1) or on a running scheduler, with at least one worker."""
    kind, value = parse_cluster(cluster)
    try:
        import logging

        from distributed import Client, LocalCluster
    except ImportError:
        raise SynthesisError(
            "--cluster needs dask.distributed: pip install 'blurtrack[cluster]'"
        ) from None
    with contextlib.ExitStack() as stack:
        if kind == "local":
            lc = LocalCluster(
                n_workers=value,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            stack.enter_context(lc)
            value = lc
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
    parse_cluster(cluster)
    if not 0 < timeout_s <= 3600:
        raise SynthesisError(f"cluster timeout must be in (0, 3600] s, got {timeout_s}")
    with open_build(spec, out, shard, progress) as run:
        if not run.todo:
            run.start()
        else:
            try:
                with connect(cluster, timeout_s) as client:
                    _run_tasks(client, run, cluster, shared_fs, png_level)
            finally:
                if shared_fs:  # temporaries of workers that died mid-write
                    remove_temporaries(run.root, run.tag)
    return run.result()
