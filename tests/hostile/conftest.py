"""Fixtures for hostile-input tests: full and read-only folders, file hashes, debris checks."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


def _mount_tmpfs(folder: Path, options: str) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    folder.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)],
        capture_output=True,
        check=False,
    )
    return r.returncode == 0


def _umount(folder: Path) -> None:
    subprocess.run(["umount", "-l", str(folder)], capture_output=True, check=False)


@pytest.fixture
def full_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A folder whose disk is (nearly) full: a 64 KiB tmpfs where we may mount one (root),
    else every ``os.replace``/``open(..., 'wb')`` into it fails with ENOSPC."""
    d = tmp_path / "full"
    if _mount_tmpfs(d, "size=64k,mode=0777"):
        try:
            yield d
        finally:
            _umount(d)
        return
    d.mkdir()
    real_open = open

    def full_open(file, mode="r", *a, **k):  # type: ignore[no-untyped-def]
        p = Path(os.fsdecode(file)) if not isinstance(file, int) else None
        if p is not None and d in p.parents and any(c in mode for c in "wax+"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(p))
        return real_open(file, mode, *a, **k)

    monkeypatch.setattr("builtins.open", full_open)
    yield d


@pytest.fixture
def readonly_dir(tmp_path: Path) -> Iterator[Path]:
    """A folder nobody can write into (a read-only tmpfs as root, else mode 0555)."""
    d = tmp_path / "ro"
    if _mount_tmpfs(d, "ro,size=64k"):
        try:
            yield d
        finally:
            _umount(d)
        return
    d.mkdir()
    d.chmod(0o555)
    try:
        yield d
    finally:
        d.chmod(0o755)


def tree_hashes(root: Path) -> dict[str, str]:
    """``relative path -> sha256`` of every file under ``root`` (for before/after checks)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def debris(*roots: Path) -> list[str]:
    """Temporary files left behind under ``roots`` (``*.tmp``, ``.*.tmp*``)."""
    found = []
    for root in roots:
        if root.exists():
            found += [
                str(p) for p in root.rglob("*") if p.name.endswith(".tmp") or ".tmp." in p.name
            ]
    return found
