"""Worker processes that end when their parent dies.

A process pool's workers outlive a parent killed with SIGKILL (the pool's shutdown never runs):
they keep their memory and, where they were busy, a core. Every pool of the project is created
with :func:`worker_initializer`, whose initializer makes the worker follow its parent:

- on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the worker the moment its
  parent goes. Linux sends that signal when the *thread* that created the worker ends, so it is
  used only for pools created on the main thread;
- everywhere, a daemon thread in the worker that checks every :data:`POLL_S` seconds whether
  its parent is still its parent (an orphan is re-parented to init or a subreaper) and ends
  the worker if not, within that time;
- the race of a parent that died before the worker set either up is closed by checking the
  parent once after both are in place.

The initializer is a :func:`functools.partial` of module-level functions, so it pickles for
``spawn`` pools as well as ``fork`` ones.
"""

from __future__ import annotations

import ctypes
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

#: Seconds between two checks of the parent by a worker's watchdog thread.
POLL_S = 0.5
#: Exit status of a worker that ends because its parent died.
ORPHAN_EXIT = 70
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def worker_initializer(
    init: Callable[..., None] | None = None, *initargs: Any
) -> functools.partial[None]:
    """The ``initializer`` of a pool whose workers end with this process; it then runs
    ``init(*initargs)`` (the pool's own initializer, if any). Call it where the pool is made.
    """
    on_main = threading.current_thread() is threading.main_thread()
    return functools.partial(_start_worker, os.getpid(), on_main, init, initargs)


def _start_worker(
    parent_pid: int,
    pdeathsig: bool,
    init: Callable[..., None] | None,
    initargs: tuple[Any, ...],
) -> None:
    """In the worker: follow the parent (see the module docstring), then the pool's init."""
    follow_parent(parent_pid, pdeathsig)
    if init is not None:
        init(*initargs)


def _set_pdeathsig() -> bool:
    """Ask Linux to SIGKILL this process when its parent dies; False where that is not there."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def follow_parent(parent_pid: int, pdeathsig: bool = True) -> None:
    """End this process (``os._exit(ORPHAN_EXIT)``) when ``parent_pid`` dies.

    ``parent_pid`` is the pid of the process that made the pool; it is normally this process's
    parent (fork, spawn). Where it is not (a fork server in between), only the watchdog runs,
    and it watches that pid directly.
    """
    direct = os.getppid() == parent_pid
    if direct and pdeathsig:
        _set_pdeathsig()

    def orphaned() -> bool:
        return os.getppid() != parent_pid if direct else not _alive(parent_pid)

    def watch() -> None:
        while True:
            time.sleep(POLL_S)
            if orphaned():
                os._exit(ORPHAN_EXIT)

    threading.Thread(target=watch, name="follow-parent", daemon=True).start()
    if orphaned():  # the parent died before the above was in place
        os._exit(ORPHAN_EXIT)
