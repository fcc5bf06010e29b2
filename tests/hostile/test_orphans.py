"""Worker processes end when their parent is killed with SIGKILL (blurtrack/workers.py).

Each case runs a parent in a subprocess whose workers write their pids (one ``os.write`` each,
so two workers' lines cannot interleave) and then wait; the test
kills the parent with SIGKILL and checks that every worker is gone within a few seconds
(a zombie that nobody has reaped yet counts as gone: it runs nothing and holds no memory).
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from blurtrack import workers
from blurtrack.detect.forkmap import can_fork

REPO = Path(__file__).resolve().parents[2]
GONE_WITHIN_S = 5.0

FORK_MAP = """
import os, time
from blurtrack.detect.forkmap import fork_map

def fn(i):
    os.write(1, f"{os.getpid()}\\n".encode())  # one write: lines never interleave
    time.sleep(120)
    return i

list(fork_map(fn, [0, 1], 2))
"""

SPAWN_POOL = """
import multiprocessing, os, time
from concurrent.futures import ProcessPoolExecutor
from blurtrack.workers import worker_initializer

def fn(i):
    os.write(1, f"{os.getpid()}\\n".encode())  # one write: lines never interleave
    time.sleep(120)
    return i

if __name__ == "__main__":
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=ctx, initializer=worker_initializer()) as pool:
        list(pool.map(fn, [0, 1]))
"""

POOL_IN_A_THREAD = """
import multiprocessing, os, threading, time
from blurtrack.workers import worker_initializer

def fn(i):
    os.write(1, f"{os.getpid()}\\n".encode())  # one write: lines never interleave
    time.sleep(120)
    return i

def run():
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(2, worker_initializer()) as pool:
        pool.map(fn, [0, 1], chunksize=1)

t = threading.Thread(target=run)
t.start()
t.join()
"""


def _gone(pid: int) -> bool:
    """True when ``pid`` no longer runs (absent, or a zombie awaiting its reaper)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True
    return stat.rsplit(")", 1)[1].split()[0] in ("Z", "X")


def _kill_parent_and_wait(tmp_path: Path, source: str) -> list[int]:
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent(source))
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(
        [sys.executable, str(script)], cwd=tmp_path, env=env, stdout=subprocess.PIPE, text=True
    )
    pids: list[int] = []
    try:
        assert proc.stdout is not None
        while len(pids) < 2:
            line = proc.stdout.readline()
            assert line, "the parent ended before its workers started"
            pids.append(int(line))
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        deadline = time.monotonic() + GONE_WITHIN_S
        while not all(_gone(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.05)
        return [p for p in pids if not _gone(p)]
    finally:
        proc.kill()
        for p in pids:  # never leave a stray worker behind, whatever the outcome
            if not _gone(p):
                os.kill(p, signal.SIGKILL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    "source",
    [
        pytest.param(
            FORK_MAP,
            id="detect-fork_map",
            marks=pytest.mark.skipif(not can_fork(), reason="no fork"),
        ),
        pytest.param(SPAWN_POOL, id="spawn-executor"),
        pytest.param(POOL_IN_A_THREAD, id="pool-made-in-a-thread"),
    ],
)
def test_workers_end_when_the_parent_is_killed(tmp_path: Path, source: str) -> None:
    assert _kill_parent_and_wait(tmp_path, source) == []


def test_the_initializer_pickles_and_runs_the_pools_own(monkeypatch: pytest.MonkeyPatch) -> None:
    init = workers.worker_initializer(print, "x")
    again = pickle.loads(pickle.dumps(init))
    assert again.args[0] == os.getpid() and again.args[2:] == (print, ("x",))
    seen: list[int] = []
    monkeypatch.setattr(workers, "follow_parent", lambda pid, pdeathsig: seen.append(pid))
    calls: list[tuple[object, ...]] = []
    workers.worker_initializer(lambda *a: calls.append(a), 1, 2)()
    assert seen == [os.getpid()] and calls == [(1, 2)]


def test_an_orphan_at_start_exits_at_once(tmp_path: Path) -> None:
    """A worker whose parent died before it set up its watch ends in its initializer."""
    code = textwrap.dedent(
        """
        import os, sys
        from blurtrack.workers import follow_parent
        follow_parent(2**22 + 12345)  # a pid that is not ours and does not run
        print("survived")
        """
    )
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == workers.ORPHAN_EXIT and "survived" not in r.stdout
