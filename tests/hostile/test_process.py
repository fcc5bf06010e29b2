"""Cases that can kill the interpreter or only show at process exit: run as subprocesses."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from blurtrack.testing.mini_session import write_synthetic_session
from tests.hostile.conftest import debris, tree_hashes


@pytest.fixture(scope="module")
def odd_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A valid session in a folder whose name holds bytes that are not UTF-8."""
    root = tmp_path_factory.mktemp("odd")
    s = Path(os.fsdecode(os.fsencode(root) + b"/s\xff\xfe"))
    write_synthetic_session(s, n_frames=2, resolution=(96, 72), grid=(3, 2))
    return s


def _run(*args: str, shell: str | None = None) -> subprocess.CompletedProcess[bytes]:
    cmd = [sys.executable, "-m", "blurtrack", *args]
    if shell is not None:
        return subprocess.run(shell, shell=True, capture_output=True, timeout=300, check=False)
    return subprocess.run(cmd, capture_output=True, timeout=300, check=False)


def test_non_utf8_path_validate_and_detect(odd_session: Path) -> None:
    """cv2.imread/imwrite segfault on surrogate-escaped str paths; the image reader never
    hands OpenCV a path."""
    before = tree_hashes(odd_session)
    r = _run("validate", str(odd_session))
    assert r.returncode == 0, r.stderr
    out = Path(os.fsdecode(os.fsencode(odd_session.parent) + b"/t\xff.parquet"))
    png = Path(os.fsdecode(os.fsencode(odd_session.parent) + b"/o\xff.png"))
    r = _run("detect", str(odd_session), "--out", str(out), "--overlay", str(png))
    assert r.returncode == 0, r.stderr
    assert out.is_file() and png.is_file()
    assert tree_hashes(odd_session) == before and debris(odd_session.parent) == []


def test_validate_into_a_closed_pipe_is_quiet(odd_session: Path) -> None:
    """``validate S | head -c0``: the reader is gone before validate prints; exit 141 quietly."""
    p = subprocess.Popen(
        [sys.executable, "-m", "blurtrack", "validate", str(odd_session)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # the reader went away
    err = p.stderr.read()
    assert p.wait(timeout=300) == 141
    assert err == b"", err
