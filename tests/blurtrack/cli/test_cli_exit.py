"""``python -m blurtrack`` ends through :func:`blurtrack.cli.exit_program`: the exit code, the
flushed output and the ``atexit`` handlers are those of an ordinary exit; only the
interpreter's teardown is skipped (shown by an object whose finaliser runs at teardown), and
with another thread still running the exit is the ordinary one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from blurtrack.testing.mini_session import write_synthetic_session

REPO = Path(__file__).resolve().parents[3]

#: An object finalised at interpreter teardown (module clean-up), a buffered line, an atexit
#: handler, then ``exit_program(CODE)``.
SCRIPT = """
import atexit, sys, threading, time
from blurtrack.cli import exit_program

class Loud:
    def __del__(self):
        print("teardown", flush=True)

keep = Loud()
atexit.register(lambda: print("atexit"))
print("buffered", end=" ")
if THREAD:
    threading.Thread(target=lambda: (time.sleep(0.3), print(" thread-done"))).start()
exit_program(CODE)
"""


def _run(code: int, thread: bool) -> subprocess.CompletedProcess[str]:
    script = SCRIPT.replace("CODE", str(code)).replace("THREAD", str(thread))
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=60
    )


def test_exit_keeps_code_output_and_atexit_but_skips_teardown() -> None:
    r = _run(3, thread=False)
    assert r.returncode == 3
    assert r.stdout.split() == ["buffered", "atexit"]  # no "teardown": it was skipped
    r0 = _run(0, thread=False)
    assert r0.returncode == 0 and r0.stdout.split() == ["buffered", "atexit"]


def test_a_running_thread_gets_the_ordinary_exit() -> None:
    r = _run(5, thread=True)
    assert r.returncode == 5
    # negative control: the ordinary exit waits for the thread and tears the interpreter down
    assert r.stdout.split() == ["buffered", "thread-done", "atexit", "teardown"]


def test_module_entry_point_writes_everything_and_keeps_exit_codes(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_synthetic_session(folder, n_frames=3, seed=5)
    out = tmp_path / "t.parquet"
    cmd = [sys.executable, "-m", "blurtrack", "detect", str(folder), "--out", str(out)]
    r = subprocess.run([*cmd, "--workers", "2"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("detect: ") and "flags:" in r.stdout
    assert out.is_file() and (tmp_path / "t.summary.json").is_file()
    import pandas as pd

    assert len(pd.read_parquet(out)) > 10
    # An existing output without --force: one line on stderr, exit 2, file unchanged.
    before = out.read_bytes()
    r2 = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    assert r2.returncode == 2 and r2.stderr.count("\n") == 1 and "exists" in r2.stderr
    assert out.read_bytes() == before
