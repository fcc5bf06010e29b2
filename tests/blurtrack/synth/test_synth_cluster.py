"""Dataset builds on a dask.distributed LocalCluster (2 worker processes on 127.0.0.1):
byte-identical to a single-process build, nothing lost when a worker or the client is killed,
one-line errors for an unreachable scheduler and a worker that lacks the inputs."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("distributed")

from blurtrack.cli import main
from blurtrack.errors import SynthesisError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import calibration_to_dict, write_calibration
from blurtrack.synth.cluster import (
    LOCAL_CONFIG,
    build_on_cluster,
    connect,
    parse_cluster,
)
from blurtrack.synth.dataset import DatasetSpec, build, read_manifest
from blurtrack.synth.triplet import TripletParams

CAL = Calibration(Camera((128, 96), (110.0, 110.0, 63.5, 47.5), readout_s=0.01))
REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def cluster() -> Iterator[tuple[str, object]]:
    """The cluster ``--cluster local:2`` starts, reached by its scheduler's address."""
    with connect("local:2") as client:
        yield client.cluster.scheduler_address, client


def make_images(root: Path) -> Path:
    rng = np.random.default_rng(0)
    for rel in ("train/a.png", "train/b.png", "test/c.png"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        img = cv2.GaussianBlur((rng.random((60, 90, 3)) * 255).astype(np.uint8), (5, 5), 1)
        cv2.imwrite(str(root / rel), img)
    return root


def spec(images: Path, count: int = 10) -> DatasetSpec:
    return DatasetSpec(
        calib=calibration_to_dict(CAL),
        gyro="synthetic:0.8",
        images=str(images),
        count=count,
        seed=7,
        params=TripletParams(size=(64, 48), exposure_ms=(10, 20)),
        group=4,
    )


def digest(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.glob("*/*/*/*"))
    }


def manifest_lines(root: Path) -> list[str]:
    return sorted((root / "manifest.jsonl").read_text().splitlines())


def test_dask_is_imported_only_by_cluster_builds() -> None:
    code = (
        "import sys, blurtrack.cli, blurtrack.io.session, blurtrack.synth.cluster;"
        "blurtrack.cli.build_parser();"
        "assert not {'dask', 'distributed'} & set(sys.modules), 'dask imported'"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_parse_cluster() -> None:
    assert parse_cluster("local:2") == ("local", 2)
    assert parse_cluster("tcp://127.0.0.1:8786") == ("remote", "tcp://127.0.0.1:8786")
    for bad in ("local:0", "local:x", "127.0.0.1:8786", "tcp://host", "http://h:1"):
        with pytest.raises(SynthesisError, match="--cluster"):
            parse_cluster(bad)


def test_killed_worker_loses_nothing_and_bytes_match(cluster, tmp_path: Path) -> None:
    address, client = cluster
    images = make_images(tmp_path / "imgs")
    ref = tmp_path / "ref"
    build(spec(images), ref)
    pids = sorted(client.run(os.getpid).values())
    killed: list[int] = []

    def kill_one(done: int, total: int) -> None:
        if done == 2 and not killed:
            os.kill(pids[0], signal.SIGKILL)  # a worker dies with tasks in flight
            killed.append(pids[0])

    out = tmp_path / "cl"
    res = build_on_cluster(spec(images), out, address, progress=kill_one)
    assert killed and res.made == 10 and res.skipped == 0
    assert digest(out) == digest(ref)  # files written by the client, byte for byte
    assert manifest_lines(out) == manifest_lines(ref)


def test_shared_fs_build_resumes_after_a_kill(cluster, tmp_path: Path) -> None:
    address, _ = cluster
    images = make_images(tmp_path / "imgs")
    ref = tmp_path / "ref"
    build(spec(images), ref)
    out = tmp_path / "sfs"
    assert build_on_cluster(spec(images), out, address, shared_fs=True).made == 10
    assert digest(out) == digest(ref)
    # A killed client: its last manifest line half written, a file gone, a temporary left.
    man = out / "manifest.jsonl"
    lines = man.read_bytes().splitlines(keepends=True)
    man.write_bytes(b"".join(lines[:-1]) + lines[-1][:30])
    rec = json.loads(lines[0])
    (out / rec["files"]["heat"]).unlink()
    (out / rec["files"]["sharp"]).with_name(".000003.png.s0of1.99-ab.tmp").write_bytes(b"x")
    res = build_on_cluster(spec(images), out, address, shared_fs=True)
    assert (res.made, res.skipped) == (2, 8)
    assert digest(out) == digest(ref) and not list(out.rglob("*.tmp"))
    assert sorted(read_manifest(man)) == list(range(10))


def test_killed_client_resumes(cluster, tmp_path: Path) -> None:
    address, _ = cluster
    images = make_images(tmp_path / "imgs")
    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "blurtrack",
        "synth",
        "--calib",
        str(cal),
        "--gyro",
        "synthetic:0.8",
        "--images",
        str(images),
        "--out",
        str(out),
        "--count",
        "16",
        "--size",
        "64x48",
        "--seed",
        "4",
        "--cluster",
        address,
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    man = out / "manifest.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if man.is_file() and man.read_bytes().count(b"\n") >= 3:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 3 <= len(read_manifest(man)) < 16
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "already done" in done.stdout
    ref = tmp_path / "ref"
    assert main([*cmd[3:11], str(ref), *cmd[12:18]]) == 0  # single process, same spec
    assert sorted(read_manifest(man)) == list(range(16))
    assert digest(out) == digest(ref) and manifest_lines(out) == manifest_lines(ref)


def test_worker_lacking_inputs_and_unreachable_scheduler(
    cluster, tmp_path: Path, capsys, monkeypatch
) -> None:
    address, client = cluster
    images = make_images(tmp_path / "imgs")
    # A relative image folder: the client (in tmp_path) sees it, the workers (started in
    # another folder) do not, like a node that mounts the photos elsewhere.
    assert all(Path(d) != tmp_path for d in client.run(os.getcwd).values())
    monkeypatch.chdir(tmp_path)
    calls: list[tuple[int, int]] = []
    with pytest.raises(
        SynthesisError, match=r"^worker tcp://127\.0\.0\.1:\d+ .* lacks the inputs: "
    ):
        build_on_cluster(
            spec(Path("imgs")), tmp_path / "x", address, progress=lambda *a: calls.append(a)
        )
    assert calls == []  # checked before the build started: no triplet, no progress
    assert not (tmp_path / "x" / "manifest.jsonl").read_bytes()
    res = build_on_cluster(spec(images), tmp_path / "x2", address)  # absolute: all see it
    assert res.made == 10

    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there once closed
    base = ["synth", "--calib", str(cal), "--gyro", "synthetic", "--images", str(images)]
    base += ["--count", "2", "--size", "48x32", "--out", str(tmp_path / "y")]
    t0 = time.monotonic()
    assert main([*base, "--cluster", f"tcp://127.0.0.1:{port}", "--cluster-timeout", "1"]) == 2
    assert time.monotonic() - t0 < 30
    err = capsys.readouterr().err
    assert "cannot reach the dask scheduler" in err and len(err.strip().splitlines()) == 1
    assert main([*base, "--cluster", "local:2", "--workers", "2"]) == 2
    assert main([*base, "--shared-fs"]) == 2
    assert main([*base, "--cluster", "nowhere"]) == 2
    assert "--cluster must be" in capsys.readouterr().err


def test_local_workers_run_like_plain_processes(cluster) -> None:
    _, client = cluster
    defaults = distributed_defaults()
    assert defaults["distributed.nanny.pre-spawn-environ"]["MALLOC_TRIM_THRESHOLD_"] is not None
    assert defaults["distributed.worker.profile"]["enabled"]  # what LOCAL_CONFIG turns off
    assert LOCAL_CONFIG["distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"] is None
    before = set(client.scheduler_info()["workers"])
    os.kill(sorted(client.run(os.getpid).values())[0], signal.SIGKILL)  # the nanny restarts it
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        now = set(client.scheduler_info()["workers"])
        if len(now) == 2 and now != before:
            break
        time.sleep(0.1)
    assert len(now) == 2 and len(now - before) == 1
    env = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
    assert len(env) == 2 and set(env.values()) == {None}
    profiling = client.run(lambda dask_worker: "profile" in dask_worker.periodic_callbacks)
    assert set(profiling.values()) == {False}


def distributed_defaults() -> dict:
    import dask
    import distributed  # noqa: F401  (registers its defaults)

    return {
        k: dask.config.get(k)
        for k in ("distributed.nanny.pre-spawn-environ", "distributed.worker.profile")
    }


MALLOC_PROBE = """
import ctypes, resource, sys
from blurtrack.synth.cluster import plain_malloc
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
SIZE, N = 20 * 2**20, 8

def faults():
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(N):
        p = libc.malloc(SIZE)
        ctypes.memset(p, 1, SIZE)
        libc.free(p)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

first, second = faults(), faults()
changed = plain_malloc()
third = faults()  # the heap grows once to hold a buffer
print(first, second, int(changed), third, faults())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc")
@pytest.mark.parametrize("dask_env", [True, False])
def test_plain_malloc_reuses_freed_buffers(dask_env: bool) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("MALLOC_TRIM_THRESHOLD_", None)
    if dask_env:
        env["MALLOC_TRIM_THRESHOLD_"] = "65536"  # what a dask nanny sets
    done = subprocess.run(
        [sys.executable, "-c", MALLOC_PROBE], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    _, second, changed, _, after = (int(v) for v in done.stdout.split())
    pages = 8 * 20 * 2**20 // os.sysconf("SC_PAGE_SIZE")  # every buffer faulted in anew
    if dask_env:
        assert second > 0.8 * pages  # a fresh mmap each time, also the second round
        assert changed == 1 and after < second / 20  # then reused from the heap
    else:
        assert changed == 0  # a plain process is left as it is: it reuses already
        assert second < pages / 20 and after < pages / 20
