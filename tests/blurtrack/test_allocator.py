"""The allocator settings of a ``blurtrack`` process (:mod:`blurtrack.allocator`)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap

import pytest

from blurtrack import allocator

#: 50 arrays of 40 MiB (above glibc's largest mmap threshold) and of 3 MiB made and freed in
#: turn, a small array kept each time, as a command's steps do; prints the minor page faults.
WORKLOAD = textwrap.dedent(
    """
    import resource, sys
    import numpy as np
    from blurtrack.allocator import keep_heap
    tuned = keep_heap() if sys.argv[1] == "tuned" else False
    keep = []
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(50):
        a = np.ones(40 << 17)
        b = np.ones(3 << 17)
        keep.append(np.ones(10))
        del a, b
    print(tuned, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    """
)


def _faults(mode: str, env: dict[str, str]) -> tuple[str, int]:
    out = subprocess.run(
        [sys.executable, "-c", WORKLOAD, mode],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    ).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_tuned_process_reuses_its_heap_instead_of_faulting_pages_in() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    # 4 KiB pages: numpy's transparent-huge-page advice would make the default's faults
    # depend on the kernel's THP setting and fragmentation (2578 against 28098 faults seen)
    env["NUMPY_MADVISE_HUGEPAGE"] = "0"
    tuned, n_tuned = _faults("tuned", env)
    assert tuned == "True"
    plain, n_plain = _faults("plain", env)  # negative control: glibc's defaults
    assert plain == "False"
    # 50 x 40 MiB is 2.5 GiB of pages, faulted in every time by default (~510 k faults
    # here); with the heap kept, the first few times only (~21 k)
    assert n_tuned < 0.2 * n_plain


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MALLOC_TOP_PAD_", "0"),
        ("MALLOC_ARENA_MAX", "2"),
        ("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=0"),
    ],
)
def test_users_malloc_settings_take_precedence(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    monkeypatch.setenv(name, value)
    assert allocator.user_tuned()
    assert allocator._apply() is False


def test_keep_heap_is_idempotent() -> None:
    first = allocator.keep_heap()
    assert allocator.keep_heap() is first
    if platform.libc_ver()[0] == "glibc" and not allocator.user_tuned():
        assert first  # glibc has mallopt and accepts every setting


def test_main_tunes_only_its_own_process(monkeypatch: pytest.MonkeyPatch) -> None:
    import blurtrack.cli as cli

    calls: list[int] = []
    monkeypatch.setattr(allocator, "keep_heap", lambda: calls.append(1) or True)
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    assert calls == []
    monkeypatch.setattr(sys, "argv", ["blurtrack", "--help"])
    with pytest.raises(SystemExit):
        cli.main()
    assert calls == [1]
