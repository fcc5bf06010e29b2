"""Benchmark of blur synthesis: triplets per second and the cost over a warp floor.

For each output size (1280x720 and 640x360) the same seeded triplets are made, interleaved, by
(a) the exact renderer (``mode=exact``), (b) the source paper's approximation (``mode=paper``)
and (c) the floor: as many ``cv2.warpPerspective`` calls on a float32 RGB image as the exact
renderer used samples (3-channel float32 as the issue defines it, and 4-channel, the layout
the renderer warps). All single-process, in memory (no file writing). Then, at both sizes,
``blurtrack synth --workers 2`` runs end to end in a subprocess (PNG + npy writing included),
and an in-process build measures CPU seconds per triplet, the load-independent figure.
Also reported: the heat maps' Bezier fit share within 0.5 px, and the error that heat-map
``stride`` adds against ``stride=1``. Prints one JSON object; ratios and medians, since the
machine is shared and noisy.

With ``--cluster ADDR`` (e.g. ``local:2``) only the cluster comparison runs: the same
``blurtrack synth`` build with ``--workers K`` (the baseline), ``--cluster ADDR`` (workers
return the files to the client) and ``--cluster ADDR --shared-fs``, interleaved ``--repeats``
times, with per-repeat ratios of triplets/s against the baseline, their medians, and a
byte-identity check of every build's files and manifest against the baseline's; then the CPU
seconds and page faults of rendering a triplet in a ``--workers`` process and in Dask workers.

    PYTHONPATH=. python bench/bench_synth.py [--n 8] [--workers 2] [--build-count 40]
    PYTHONPATH=. python bench/bench_synth.py --cluster local:2 [--build-count 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import calibration_to_dict, write_calibration
from blurtrack.synth.dataset import DatasetSpec, build
from blurtrack.synth.images import camera_for_size, list_images, load_image
from blurtrack.synth.motion import open_source
from blurtrack.synth.triplet import TripletParams, make_triplet, triplet_rng

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CALIB = Calibration(Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5), readout_s=0.02))


def floor_time(n: int, size: tuple[int, int], rng: np.random.Generator, channels: int = 3) -> float:
    """Seconds of ``n`` float32 ``cv2.warpPerspective`` calls (the issue's floor: 3 channels;
    with 4, the vectorised kernel the renderer itself uses)."""
    W, H = size
    img = rng.random((H, W, channels), dtype=np.float32)
    M = np.array([[1.0, 0.002, 1.3], [-0.002, 1.0, 0.7], [1e-6, -1e-6, 1.0]])
    t0 = time.perf_counter()
    for _ in range(n):
        cv2.warpPerspective(
            img,
            M,
            (W, H),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REFLECT_101,
        )
    return time.perf_counter() - t0


def bench_size(size: tuple[int, int], n: int, gyro: str, images: Path) -> dict:
    src = open_source(gyro)
    names = list_images(images)
    rng = np.random.default_rng(0)
    exact_t, exact_cpu, paper_t, floor_t, floor4_t, samples, fits = [], [], [], [], [], [], []
    img_diff, heat_diff = [], []
    for i in range(n):
        img = load_image(images, names[i % len(names)])
        t0, c0 = time.perf_counter(), time.process_time()
        tr = make_triplet(img, CALIB, src, TripletParams(size=size), triplet_rng(1, i))
        exact_t.append(time.perf_counter() - t0)
        exact_cpu.append(time.process_time() - c0)
        t0 = time.perf_counter()
        pp = make_triplet(
            img, CALIB, src, TripletParams(size=size, mode="paper"), triplet_rng(1, i)
        )
        paper_t.append(time.perf_counter() - t0)
        both = tr.valid & pp.valid
        img_diff.append(float(np.mean(np.abs(tr.blur.astype(float) - pp.blur)[both])))
        heat_diff.append(float(np.percentile(np.abs(tr.heat - pp.heat), 99)))
        floor_t.append(floor_time(tr.info["samples"], size, rng))
        floor4_t.append(floor_time(tr.info["samples"], size, rng, 4))
        samples.append(tr.info["samples"])
        fits.append(tr.info["bezier_fit"]["within_0.5px"])
    ratio = [e / f for e, f in zip(exact_t, floor_t, strict=True)]
    return {
        "size": list(size),
        "triplets": n,
        "median_samples": statistics.median(samples),
        "exact_triplets_per_s": 1 / statistics.median(exact_t),
        "exact_cpu_s_median": statistics.median(exact_cpu),
        "paper_triplets_per_s": 1 / statistics.median(paper_t),
        "floor_triplets_per_s": 1 / statistics.median(floor_t),
        "floor_4ch_triplets_per_s": 1 / statistics.median(floor4_t),
        "exact_over_floor_median": statistics.median(ratio),
        "exact_over_floor_4ch_median": statistics.median(
            [e / f for e, f in zip(exact_t, floor4_t, strict=True)]
        ),
        "paper_over_floor_median": statistics.median(
            [p / f for p, f in zip(paper_t, floor_t, strict=True)]
        ),
        "paper_vs_exact_blur_mean_abs_8bit": statistics.median(img_diff),
        "paper_vs_exact_heat_p99_px": statistics.median(heat_diff),
        "bezier_fit_within_0.5px_mean": float(np.mean(fits)),
        "bezier_fit_within_0.5px_min": float(np.min(fits)),
    }


def stride_error(gyro: str, size: tuple[int, int]) -> dict:
    src = open_source(gyro)
    cam = camera_for_size(CALIB.camera, *size)
    out = {}
    for i in range(3):
        rng = triplet_rng(5, i)
        seg = src.segment(rng, 0.045, 0.05)
        m = BlurModel(Calibration(cam), seg.trace)
        full, _ = m.heat_maps(seg.frame_t_s, 0.025, 16, None, 1)
        for s in (4, 8, 16):
            approx, _ = m.heat_maps(seg.frame_t_s, 0.025, 16, None, s)
            e = np.abs(approx - full)
            d = out.setdefault(f"stride_{s}", {"max_px": 0.0, "p99_px": 0.0})
            d["max_px"] = max(d["max_px"], float(e.max()))
            d["p99_px"] = max(d["p99_px"], float(np.percentile(e, 99)))
    return out


def fit_share(gyro: str, n: int) -> dict:
    """Share of 1280x720 pixels whose trajectory the quadratic Bezier fits within 0.5 px, over
    ``n`` random shake segments per exposure (the paper claims 99.9 %)."""
    src = open_source(gyro)
    cam = camera_for_size(CALIB.camera, 1280, 720)
    out = {}
    for exp_ms in (10.0, 20.0, 30.0, 60.0):
        shares = []
        for i in range(n):
            seg = src.segment(triplet_rng(9, i), cam.readout_s + exp_ms * 1e-3, 0.05)
            _, err = BlurModel(Calibration(cam), seg.trace).heat_maps(
                seg.frame_t_s, exp_ms * 1e-3, 16, None, 8
            )
            shares.append(float(np.mean(err <= 0.5)))
        out[f"exposure_{exp_ms:g}ms"] = {
            "mean": float(np.mean(shares)),
            "p05": float(np.percentile(shares, 5)),
            "min": float(np.min(shares)),
        }
    return out


def cli_build(
    size: tuple[int, int],
    count: int,
    workers: int,
    gyro: str,
    images: Path,
    tmp: Path,
    extra: tuple[str, ...] = (),
    name: str = "",
) -> dict:
    """``blurtrack synth --workers K`` end to end in a subprocess: wall time (start-up
    included), the steady rate between the 2nd and the last finished triplet (from the heat
    files' modification times), the CPU seconds of the command and its workers (a local
    cluster's scheduler, nannies and workers included), the seconds until the first triplet
    was written (start-up) and after the last one (shutting down)."""
    calib = tmp / f"calib{size[0]}.yaml"
    write_calibration(CALIB, calib)
    out = tmp / f"cli{size[0]}{name}"
    cmd = [
        sys.executable,
        "-m",
        "blurtrack",
        "synth",
        "--calib",
        str(calib),
        "--gyro",
        gyro,
        "--images",
        str(images),
        "--out",
        str(out),
        "--count",
        str(count),
        "--seed",
        "3",
        "--size",
        f"{size[0]}x{size[1]}",
        *(extra or ("--workers", str(workers))),
    ]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0, epoch0 = time.perf_counter(), time.time()
    subprocess.run(cmd, check=True, env=env, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    done = sorted(p.stat().st_mtime for p in out.glob("*/*/heat/*.npy"))
    steady = (len(done) - 2) / (done[-1] - done[1]) if len(done) > 3 else None
    return {
        "size": list(size),
        "workers": workers,
        "triplets": len(done),
        "wall_s": wall,
        "triplets_per_s": len(done) / wall,
        "steady_triplets_per_s": steady,
        "cpu_s_per_triplet_incl_startup": cpu / len(done),
        "first_triplet_s": done[0] - epoch0 if done else None,
        "after_last_triplet_s": wall - (done[-1] - epoch0) if done else None,
    }


def tree_digest(root: Path) -> str:
    """One hash over every triplet file (path and bytes) and the sorted manifest lines."""
    h = hashlib.sha256()
    for p in sorted(root.glob("*/*/*/*")):
        h.update(p.relative_to(root).as_posix().encode() + hashlib.sha256(p.read_bytes()).digest())
    for line in sorted((root / "manifest.jsonl").read_text().splitlines()):
        h.update(line.encode())
    return h.hexdigest()


def cluster_compare(
    cluster: str,
    workers: int,
    count: int,
    repeats: int,
    gyro: str,
    images: Path,
    size: tuple[int, int] = (1280, 720),
) -> dict:
    """``--workers K`` against ``--cluster`` (client writes) and ``--cluster --shared-fs``,
    interleaved, the whole command timed in a subprocess."""
    modes = {
        "workers": (),
        "cluster": ("--cluster", cluster),
        "cluster_shared_fs": ("--cluster", cluster, "--shared-fs"),
    }
    runs: dict[str, list[dict]] = {m: [] for m in modes}
    identical = True
    for r in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            ref = None
            for m, extra in modes.items():
                b = cli_build(size, count, workers, gyro, images, Path(tmp), extra, m)
                d = tree_digest(Path(tmp) / f"cli{size[0]}{m}")
                ref = ref or d
                identical &= d == ref
                b["repeat"] = r
                runs[m].append(b)
                for p in Path(tmp).glob(f"cli{size[0]}{m}/*/*"):  # keep the disk small
                    if p.is_dir():
                        subprocess.run(["rm", "-rf", str(p)], check=True)
    base = runs["workers"]
    out: dict = {
        "cluster": cluster,
        "workers": workers,
        "size": list(size),
        "triplets": count,
        "repeats": repeats,
    }
    for m in ("cluster", "cluster_shared_fs"):
        for key in ("triplets_per_s", "steady_triplets_per_s"):
            ratios = [
                c[key] / b[key] for c, b in zip(runs[m], base, strict=True) if c[key] and b[key]
            ]
            out[f"{m}_over_workers_{key}"] = ratios
            out[f"{m}_over_workers_{key}_median"] = statistics.median(ratios) if ratios else None
    for m, rs in runs.items():
        out[f"{m}_triplets_per_s_median"] = statistics.median(x["triplets_per_s"] for x in rs)
        out[f"{m}_steady_triplets_per_s_median"] = statistics.median(
            x["steady_triplets_per_s"] or 0.0 for x in rs
        )
        for key in ("cpu_s_per_triplet_incl_startup", "first_triplet_s", "after_last_triplet_s"):
            out[f"{m}_{key}_median"] = statistics.median(x[key] or 0.0 for x in rs)
    out["byte_identical_to_workers_build"] = identical
    out["target_within_10pct_overall"] = out["cluster_over_workers_triplets_per_s_median"] >= 0.9
    out["target_within_10pct_steady"] = (
        out["cluster_over_workers_steady_triplets_per_s_median"] or 0
    ) >= 0.9
    out["runs"] = runs
    return out


def _render_cost(spec_dict: dict, jobs: list, plain_malloc: bool) -> dict:
    """CPU s, system CPU s and minor page faults per triplet of ``Renderer.render`` on the
    calling thread, after one warm-up triplet (``plain_malloc``: call the cluster's fix)."""
    from blurtrack.synth import cluster
    from blurtrack.synth.dataset import Renderer

    cv2.setNumThreads(1)
    fixed = cluster.plain_malloc() if plain_malloc else None
    r = Renderer(spec_dict)
    r.render(jobs[0])
    a = resource.getrusage(resource.RUSAGE_THREAD)
    for job in jobs[1:]:
        r.render(job)
    b = resource.getrusage(resource.RUSAGE_THREAD)
    n = len(jobs) - 1
    return {
        "cpu_s": (b.ru_utime - a.ru_utime + b.ru_stime - a.ru_stime) / n,
        "system_cpu_s": (b.ru_stime - a.ru_stime) / n,
        "minor_faults": (b.ru_minflt - a.ru_minflt) / n,
        "malloc_trim_env": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
        "plain_malloc_changed": fixed,
    }


def render_in_workers(gyro: str, images: Path, size: tuple[int, int], n: int = 6) -> dict:
    """The cost of rendering a triplet in a ``--workers`` process, in a worker of the cluster
    ``--cluster local:1`` starts, and in a worker of a LocalCluster with Dask's defaults
    (as ``dask worker`` runs), without and with :func:`plain_malloc`."""
    import logging
    import multiprocessing

    from distributed import Client, LocalCluster

    from blurtrack.synth.cluster import connect
    from blurtrack.synth.dataset import plan

    spec = DatasetSpec(
        calibration_to_dict(CALIB), gyro, str(images), 64, 3, TripletParams(size=size)
    )
    jobs = plan(spec, list_images(images), open_source(gyro).tag)[: n + 1]
    args, out = (spec.to_dict(), jobs), {}
    saved = dict(os.environ)
    try:
        os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
        with multiprocessing.get_context("spawn").Pool(1) as pool:  # as --workers starts them
            out["workers_process"] = pool.apply(_render_cost, (*args, False))
        with connect("local:1") as client:
            out["cluster_local_worker"] = client.submit(_render_cost, *args, False).result()
        kw = {"host": "127.0.0.1", "dashboard_address": None, "silence_logs": logging.ERROR}
        with LocalCluster(n_workers=1, threads_per_worker=1, **kw) as lc, Client(lc) as client:
            for fix in (False, True):  # fresh tasks: a new Renderer each
                key = "dask_defaults_worker" + ("_plain_malloc" if fix else "")
                out[key] = client.submit(_render_cost, *args, fix, pure=False).result()
    finally:  # a nanny writes its variables into this process's environment
        os.environ.clear()
        os.environ.update(saved)
    return out


def inprocess_cpu(size: tuple[int, int], count: int, gyro: str, images: Path, tmp: Path) -> float:
    """CPU seconds per triplet of an in-process (1 worker) build, files written; the machine
    is shared, so CPU seconds say more than wall seconds about an idle 2-core machine."""

    def mk(n: int, seed: int) -> DatasetSpec:
        return DatasetSpec(
            calib=calibration_to_dict(CALIB),
            gyro=gyro,
            images=str(images),
            count=n,
            seed=seed,
            params=TripletParams(size=size),
        )

    build(mk(1, 5), tmp / f"warm{size[0]}", workers=1)  # imports, shake file, caches
    c0 = time.process_time()
    res = build(mk(count, 4), tmp / f"cpu{size[0]}", workers=1)
    return (time.process_time() - c0) / res.made


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=8, help="triplets per size")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--build-count",
        type=int,
        default=40,
        help="triplets of the 1280x720 builds (twice as many at 640x360)",
    )
    ap.add_argument("--fit-segments", type=int, default=50)
    ap.add_argument(
        "--cluster",
        default=None,
        help="only compare --cluster ADDR (e.g. local:2) with --workers on 1280x720 builds",
    )
    ap.add_argument("--repeats", type=int, default=3, help="interleaved repeats (--cluster)")
    ap.add_argument("--size", default="1280x720", help="output WxH of the --cluster builds")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    shake = DATA / "real" / "gyrodeblurnet-shake"
    gyro = str(shake) if shake.is_dir() else "synthetic:0.7"
    images = DATA / "backgrounds" / "bsds500"
    if not images.is_dir():
        raise SystemExit(f"backgrounds not found at {images}")
    if args.cluster:
        start = os.getloadavg()[0]
        w, h = (int(v) for v in args.size.split("x"))
        res = cluster_compare(
            args.cluster, args.workers, args.build_count, args.repeats, gyro, images, (w, h)
        )
        res["render_cost_per_triplet"] = render_in_workers(gyro, images, (w, h))
        res.update(load_average_1min_start=start, load_average_1min_end=os.getloadavg()[0])
        print(json.dumps(res, indent=2))
        return
    result = {
        "gyro": Path(gyro).name,
        "calibration": "1280x720 f=1000 px readout 20 ms",
        "exposure_ms": [10, 30],
        "load_average_1min_start": os.getloadavg()[0],
    }
    result["sizes"] = [
        bench_size((1280, 720), args.n, gyro, images),
        bench_size((640, 360), 2 * args.n, gyro, images),
    ]
    result["heat_stride_error_vs_stride_1"] = {
        f"{w}x{h}": stride_error(gyro, (w, h)) for w, h in ((1280, 720), (640, 360))
    }
    result["bezier_fit_within_0.5px_1280x720"] = fit_share(gyro, args.fit_segments)
    builds = []
    with tempfile.TemporaryDirectory() as tmp:
        for size, count in (((1280, 720), args.build_count), ((640, 360), 2 * args.build_count)):
            b = cli_build(size, count, args.workers, gyro, images, Path(tmp))
            cpu = inprocess_cpu(size, max(4, count // 2), gyro, images, Path(tmp))
            b.update(
                {
                    "cpu_s_per_triplet_in_process": cpu,
                    "estimated_idle_2core_triplets_per_s": 2.0 / cpu,
                }
            )
            builds.append(b)
    result["builds"] = builds
    big, big_build = result["sizes"][0], builds[0]
    result["targets"] = {
        "exact_within_3x_of_floor_1280x720": big["exact_over_floor_median"] <= 3.0,
        "build_5_triplets_per_s_1280x720": big_build["triplets_per_s"] >= 5.0,
        "build_steady_5_triplets_per_s_1280x720": (big_build["steady_triplets_per_s"] or 0) >= 5.0,
        "estimated_idle_2core_5_triplets_per_s": big_build["estimated_idle_2core_triplets_per_s"]
        >= 5.0,
        "load_average_1min_end": os.getloadavg()[0],
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
