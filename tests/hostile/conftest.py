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


# ------------------------------------------------------------------ subprocess runs
REPO = Path(__file__).resolve().parents[2]


def run_cli(
    program: str,
    *args: str | os.PathLike[str],
    fsize: int | None = None,
    timeout: float = 300,
) -> subprocess.CompletedProcess[str]:
    """Run ``python -m PROGRAM ARGS`` (``blurtrack`` or ``gamd``) in a fresh interpreter with
    stderr not a terminal. ``fsize``: the largest file (bytes) the process may write
    (``RLIMIT_FSIZE``, with ``SIGXFSZ`` ignored so a write past it fails with ``EFBIG``): a
    full disk without a disk."""
    import resource
    import signal
    import sys

    def limit() -> None:
        if fsize is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONDONTWRITEBYTECODE="1")
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-m", program, *map(os.fsdecode, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        env=env,
        cwd=REPO,
        preexec_fn=limit,
    )


def assert_refused(r: subprocess.CompletedProcess[str], needle: str = "") -> str:
    """The refusal contract: exit 1 or 2, exactly one non-empty line on stderr (no traceback,
    warning or progress bar before it), containing ``needle``; returns the line."""
    lines = r.stderr.splitlines()
    assert r.returncode in (1, 2), (r.returncode, r.stderr[-3000:])
    assert len(lines) == 1 and lines[0].strip(), r.stderr[-3000:]
    assert "Traceback" not in r.stderr and needle in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ shared inputs
class World:
    """Inputs every command can use, built once per test session (copy before changing):
    two laser-grid sessions ``S`` (with its true streak table) and ``S2``, a calibration, a
    folder of photos, and a GAMD dataset with a tiny training config."""

    def __init__(self, root: Path) -> None:
        import cv2
        import numpy as np
        import yaml

        from blurtrack.io import streaks as streak_table
        from blurtrack.io.calibration import write_calibration
        from blurtrack.io.session import load_session
        from blurtrack.testing.mini_session import write_synthetic_session

        self.root = root
        self.S = root / "S"
        self.S2 = root / "S2"
        write_synthetic_session(self.S, n_frames=12, resolution=(160, 120), grid=(5, 4))
        write_synthetic_session(self.S2, n_frames=3, resolution=(160, 120), grid=(4, 3), seed=1)
        session = load_session(self.S)
        streak_table.write(streak_table.from_truth(session.truth), self.S / "streaks.parquet")
        self.calib = root / "calib.yaml"
        write_calibration(session.initial_calibration(), self.calib)
        rng = np.random.default_rng(0)
        self.images = root / "photos"
        for rel in ("train/a.png", "train/b.png", "test/c.png"):
            (self.images / rel).parent.mkdir(parents=True, exist_ok=True)
            img = cv2.GaussianBlur((rng.random((60, 90, 3)) * 255).astype(np.uint8), (5, 5), 1)
            _, buf = cv2.imencode(".png", img)
            (self.images / rel).write_bytes(buf.tobytes())
        self.data = root / "gamd_data"
        self._write_gamd_dataset(self.data)
        self.config = root / "train.yaml"
        self.config.write_text(yaml.safe_dump(self.train_config()))

    @staticmethod
    def _write_gamd_dataset(root: Path) -> None:
        import json

        import cv2
        import numpy as np

        rng = np.random.default_rng(0)
        lines = []
        for i in range(4):
            folder = root / "train" / "g0"
            for sub in ("sharp", "blur"):
                (folder / sub).mkdir(parents=True, exist_ok=True)
                img = (rng.random((24, 32, 3)) * 255).astype(np.uint8)
                _, buf = cv2.imencode(".png", img)
                (folder / sub / f"{i:05d}.png").write_bytes(buf.tobytes())
            (folder / "heat").mkdir(exist_ok=True)
            np.save(folder / "heat" / f"{i:05d}.npy", rng.normal(0, 2, (6, 24, 32)).astype("f4"))
            lines.append(json.dumps({"split": "train", "name": "g0", "stem": f"{i:05d}"}))
        (root / "manifest.jsonl").write_text("\n".join(lines) + "\n")
        (root / "dataset.yaml").write_text("format: blurtrack-dataset/1\n")

    def train_config(self, **model: object) -> dict[str, object]:
        return {
            "model": {"name": "gamd", "preset": "tiny", **model},
            "data": {"root": str(self.data), "crop": 16, "heat_scale_px": 4.0},
            "train": {
                "out_dir": str(self.root / "runs" / "default"),
                "steps": 2,
                "batch_size": 2,
                "lr": 1e-3,
                "milestones": [],
                "checkpoint_every": 2,
                "log_every": 1,
                "tensorboard": False,
                "device": "cpu",
                "threads": 1,
            },
        }

    def synth_args(self, out: Path, *more: str) -> list[str]:
        return [
            "synth",
            "--calib",
            str(self.calib),
            "--gyro",
            "synthetic:0.8",
            "--images",
            str(self.images),
            "--count",
            "3",
            "--size",
            "48x32",
            "--exposure-ms",
            "10:20",
            "--out",
            str(out),
            *more,
        ]


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    return World(tmp_path_factory.mktemp("world"))


def all_inputs(w: World) -> dict[str, str]:
    """Checksums of every input of :class:`World` (sessions, calibration, photos, dataset)."""
    out = {}
    for folder in (w.S, w.S2, w.images, w.data):
        out.update({f"{folder.name}/{k}": v for k, v in tree_hashes(folder).items()})
    out["calib.yaml"] = hashlib.sha256(w.calib.read_bytes()).hexdigest()
    return out
