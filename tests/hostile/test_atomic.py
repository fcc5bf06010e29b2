"""The one atomic writer: umask permissions, cleanup on every error, long names, one-line errors."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import pytest

from blurtrack.errors import BlurTrackError
from blurtrack.io import atomic
from tests.hostile.conftest import debris


def test_permissions_follow_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        p = atomic.write_text_atomic(tmp_path / "a.yaml", "x: 1\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    old = os.umask(0o077)
    try:
        atomic.write_text_atomic(tmp_path / "b.yaml", "x: 1\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "b.yaml").stat().st_mode) == 0o600


def test_replaces_whole_file_and_leaves_no_temp(tmp_path: Path) -> None:
    p = tmp_path / "f.txt"
    p.write_text("old")
    atomic.write_bytes_atomic(p, b"new")
    assert p.read_bytes() == b"new"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["f.txt"]


@pytest.mark.parametrize("n", [200, 240, 253, 255])
def test_long_names(tmp_path: Path, n: int) -> None:
    name = "n" * (n - 4) + ".png"
    assert len(atomic.temp_name(name, "s0of1").encode()) <= atomic.NAME_MAX
    atomic.write_bytes_atomic(tmp_path / name, b"x")
    assert (tmp_path / name).read_bytes() == b"x"
    assert debris(tmp_path) == []


def test_multibyte_long_name_stays_decodable() -> None:
    name = "é" * 127  # 254 bytes
    t = atomic.temp_name(name)
    assert len(os.fsencode(t)) <= atomic.NAME_MAX and "\udcc3" not in t


@pytest.mark.parametrize("exc", [OSError(errno.ENOSPC, "No space"), KeyboardInterrupt()])
def test_temp_removed_on_error(tmp_path: Path, exc: BaseException) -> None:
    p = tmp_path / "f.txt"
    p.write_text("old")

    def boom(f):  # type: ignore[no-untyped-def]
        f.write(b"half")
        raise exc

    with pytest.raises(BlurTrackError if isinstance(exc, OSError) else KeyboardInterrupt) as ei:
        atomic.write_atomic(p, boom)
    assert p.read_text() == "old"
    assert debris(tmp_path) == []
    if isinstance(exc, OSError):
        msg = str(ei.value)
        assert "\n" not in msg and "f.txt" in msg and "no space" in msg
        assert isinstance(ei.value, OSError) and ei.value.errno == errno.ENOSPC


def test_full_disk(full_dir: Path) -> None:
    with pytest.raises(atomic.OutputError, match="no space left"):
        atomic.write_bytes_atomic(full_dir / "big.bin", b"\0" * (1 << 20))
    assert debris(full_dir) == []
    assert not (full_dir / "big.bin").exists()


def test_read_only_folder(readonly_dir: Path) -> None:
    with pytest.raises(atomic.OutputError, match="cannot write") as ei:
        atomic.write_text_atomic(readonly_dir / "x.json", "{}")
    assert "\n" not in str(ei.value)
    with pytest.raises(atomic.OutputError, match="cannot create the folder"):
        atomic.write_text_atomic(readonly_dir / "sub" / "x.json", "{}")


def test_json_is_always_valid(tmp_path: Path) -> None:
    import json

    import numpy as np

    p = atomic.write_json_atomic(
        tmp_path / "s.json", {"a": float("nan"), "b": [np.float32(np.inf), 1.5], "c": np.arange(2)}
    )
    assert json.loads(p.read_text()) == {"a": None, "b": [None, 1.5], "c": [0, 1]}
