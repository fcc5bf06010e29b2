"""Write a simulated recording as a session folder with its truth.yaml."""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable, Generator
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.io.calibration import calibration_to_dict
from blurtrack.io.session import SessionWriter, load_session
from blurtrack.workers import worker_initializer
from rigs.sim.errors import SimError
from rigs.sim.rig import SimRig
from rigs.sim.truthio import write_truth

TRUTH_FORMAT = "blurtrack-truth/1"
#: Frames per task of a worker process.
CHUNK_FRAMES = 4
MAX_WORKERS = 64

_worker_rig: SimRig | None = None


def _init_worker(rig: SimRig) -> None:
    global _worker_rig
    _worker_rig = rig
    cv2.setNumThreads(1)  # one process per core; OpenCV's own threads would compete


def _render_chunk(times_ns: list[int]) -> list[np.ndarray]:
    assert _worker_rig is not None  # set by _init_worker in every worker
    return [_worker_rig.render_frame(t * 1e-9) for t in times_ns]


def rendered_frames(rig: SimRig, workers: int = 1) -> Generator[np.ndarray, None, None]:
    """Every frame of ``rig`` in order, rendered by ``workers`` processes (spawned, each with a
    pickled copy of the rig: forking a process whose OpenCV threads have run can deadlock;
    chunks of :data:`CHUNK_FRAMES`). Each frame depends on its timestamp only (its noise
    stream is keyed by it), so the frames are identical whatever ``workers``."""
    times = [int(t) for t in rig.frame_times_ns]
    if not 1 <= int(workers) <= MAX_WORKERS:
        raise SimError(f"workers must be in [1, {MAX_WORKERS}], got {workers}")
    if workers == 1 or len(times) <= CHUNK_FRAMES:
        for t in times:
            yield rig.render_frame(t * 1e-9)
        return
    chunks = [times[i : i + CHUNK_FRAMES] for i in range(0, len(times), CHUNK_FRAMES)]
    ctx = multiprocessing.get_context("spawn")
    start = worker_initializer(_init_worker, rig)  # workers end when this process dies
    with ProcessPoolExecutor(int(workers), mp_context=ctx, initializer=start) as pool:
        window = 2 * int(workers)  # chunks in flight: bounds the frames held in memory
        pending: list[Future[list[np.ndarray]]] = [
            pool.submit(_render_chunk, c) for c in chunks[:window]
        ]
        nxt = len(pending)
        while pending:
            done = pending.pop(0).result()
            if nxt < len(chunks):
                pending.append(pool.submit(_render_chunk, chunks[nxt]))
                nxt += 1
            yield from done


def copied_frames(rig: SimRig, source: str | Path) -> Generator[np.ndarray, None, None]:
    """The frames of session ``source``, which ``rig`` must render identically: same frame
    times, and its first and last frames re-rendered here equal to the stored ones (a session
    that differs only in the gyro, e.g. its rate, shares the frames)."""
    s = load_session(source)
    stored = [int(t) for t in s.frames.timestamp_ns]
    if stored != [int(t) for t in rig.frame_times_ns]:
        raise SimError(f"{source}: its frame times are not this rig's")
    for i in sorted({0, len(stored) - 1}):
        if not np.array_equal(s.read_image(i), rig.render_frame(stored[i] * 1e-9)):
            raise SimError(f"{source}: frame {i} is not what this rig renders")
    for i in range(len(stored)):
        yield s.read_image(i)


def write_session(
    rig: SimRig,
    out: str | Path,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
    frames_from: str | Path | None = None,
) -> dict[str, Any]:
    """Render every frame of ``rig`` into the session folder ``out`` (must be new or empty).

    Gyro samples go in first, then each frame as it is rendered (by ``workers`` processes,
    :func:`rendered_frames`; or taken from the session ``frames_from``, :func:`copied_frames`),
    then ``truth.yaml``. Returns a summary (counts, streak lengths, saturation, the true offset
    and readout, timings).
    """
    t0 = time.perf_counter()
    frames: list[dict[str, Any]] = []
    lengths: list[float] = []
    inside = saturated = 0
    top = (1 << rig.preset.bit_depth) - 1
    t_imu_ns = rig.gyro_times_ns()
    with SessionWriter(out, rig.nominal_meta()) as w:
        w.add_imu(t_imu_ns, rig.sample_gyro(t_imu_ns * 1e-9))
        render_s = 0.0
        source = (
            rendered_frames(rig, workers)
            if frames_from is None
            else copied_frames(rig, frames_from)
        )
        try:
            for i, ts_ns in enumerate(rig.frame_times_ns):
                tr = time.perf_counter()
                img = next(source)
                render_s += time.perf_counter() - tr
                w.add_frame(int(ts_ns), img, rig.exposure_ns)
                fr = rig.frame_truth(i)
                frames.append(fr)
                lengths.extend(s["length_px"] for s in fr["streaks"])
                inside += sum(s["inside"] for s in fr["streaks"])
                saturated += int(np.count_nonzero(img >= top))
                if progress is not None:
                    progress(i + 1, rig.n_frames)
        finally:
            source.close()  # shuts the worker pool down
        truth = {
            "format": TRUTH_FORMAT,
            "calibration": calibration_to_dict(rig.calibration),
            "simulator": rig.simulator_info(),
            "frames": frames,
        }
        tt = time.perf_counter()
        write_truth(Path(out) / "truth.yaml", truth)
        truth_s = time.perf_counter() - tt
    cam = rig.camera
    n_px = rig.n_frames * cam.width * cam.height
    return {
        "session": str(out),
        "preset": rig.preset.name,
        "seed": rig.seed,
        "frames": rig.n_frames,
        "imu_samples": int(t_imu_ns.size),
        "resolution": list(cam.resolution),
        "exposure_s": rig.preset.exposure_s,
        "streaks": len(lengths),
        "streaks_inside": int(inside),
        "streak_length_px": {
            "median": float(np.median(lengths)) if lengths else 0.0,
            "max": float(np.max(lengths)) if lengths else 0.0,
        },
        "saturated_fraction": saturated / n_px,
        "true": {
            "intrinsics": list(cam.intrinsics),
            "readout_s": cam.readout_s,
            "timeshift_cam_imu_s": rig.calibration.timeshift_cam_imu_s,
            "misalignment_deg": rig.misalignment_deg,
        },
        "motion": rig.motion_info,
        "seconds": {"total": time.perf_counter() - t0, "render": render_s, "truth": truth_s},
    }
