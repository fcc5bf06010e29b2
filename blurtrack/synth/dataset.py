"""The training-triplet dataset: spec, plan, and the build on the cores of one machine.

Layout (GoPro style)::

    DATASET/dataset.yaml                        format: blurtrack-dataset/1, identity, spec
    DATASET/manifest.jsonl                      one JSON object per triplet (sorted by index)
    DATASET/manifest-shard<I>.jsonl             per-shard manifests before ``synth-merge``
    DATASET/{train,test}/<name>/sharp/<stem>.png   8-bit sRGB
    DATASET/{train,test}/<name>/blur/<stem>.png
    DATASET/{train,test}/<name>/heat/<stem>.npy    float32 (6, H, W)

Triplet ``i`` is fully determined by ``(spec, i)``: its image is ``images[perm[i % n]]`` with a
seeded permutation, its randomness comes from ``SeedSequence([seed, i])``. Files are written to a
hidden temporary name and renamed into place, and the manifest line is appended (and fsynced)
only after all files are in place, so a killed build leaves only finished triplets under
final names; a rerun skips every triplet whose manifest line and files exist and are complete
(zero-byte, truncated or undecodable files are made again and reported;
:mod:`blurtrack.synth.store`). The spec and plan are in :mod:`blurtrack.synth.spec`, the
build run (lock, checks, resume) in :mod:`blurtrack.synth.run`. Shard ``I/N`` builds the
indices ``i % N == I`` into ``manifest-shardI.jsonl``; shards are combined by
:func:`blurtrack.synth.merge.merge`. The same build runs on a Dask cluster through
:mod:`blurtrack.synth.cluster`, which shares :func:`~blurtrack.synth.run.open_build` and
:class:`Renderer` with this module.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError, SynthesisError
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.synth.images import load_image
from blurtrack.synth.motion import open_source
from blurtrack.synth.run import BuildResult, BuildRun, inputs_identity, open_build
from blurtrack.synth.spec import FORMAT, MAX_COUNT, DatasetSpec, Job, parse_shard, plan
from blurtrack.synth.store import read_manifest, write_atomic
from blurtrack.synth.triplet import TripletParams, draw_triplet
from blurtrack.workers import worker_initializer

# The spec and the build run live in their own modules; their names stay importable here.
__all__ = [
    "FORMAT",
    "MAX_COUNT",
    "BuildResult",
    "BuildRun",
    "DatasetSpec",
    "Job",
    "build",
    "inputs_identity",
    "open_build",
    "parse_shard",
    "plan",
    "read_manifest",
]

#: Largest worker count accepted.
MAX_WORKERS = 64
#: PNG deflate level of sharp and blurred images. 0 (stored) encodes about twice as fast as 1
#: and costs ~1.5 MB per 1280x720 image, small next to the 22 MB of its heat maps.
DEFAULT_PNG_LEVEL = 0


def _png(img: np.ndarray, level: int = 0) -> bytes:
    flags = [cv2.IMWRITE_PNG_COMPRESSION, int(level)]
    if level == 0:  # row filters only help deflate; unfiltered stored PNG encodes 4x faster
        flags += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", img, flags)
    if not ok:
        raise SynthesisError("PNG encoding failed")
    return buf.tobytes()


# ------------------------------------------------------------------ worker side
class Renderer:
    """What a worker holds (spec, calibration, gyro source); renders a job to its manifest
    record and its files, ``{relative path: PNG bytes or array for .npy}``."""

    def __init__(self, spec_dict: dict[str, Any], png_level: int = DEFAULT_PNG_LEVEL) -> None:
        self.spec = DatasetSpec.from_dict(spec_dict)
        self.png = int(png_level)
        self.calib = calibration_from_dict(self.spec.calib)
        self.source = open_source(self.spec.gyro)

    def render(self, job: Job) -> tuple[dict[str, Any], dict[str, bytes | np.ndarray]]:
        spec = self.spec
        try:
            image = load_image(spec.images, job.image)
            tr, under = draw_triplet(
                image, self.calib, self.source, spec.params, spec.seed, job.index
            )
        except BlurTrackError as exc:
            raise SynthesisError(f"triplet {job.index} ({job.image}): {exc}") from None
        data: dict[str, bytes | np.ndarray] = {
            "sharp": _png(tr.sharp, self.png),
            "blur": _png(tr.blur, self.png),
            "heat": tr.heat,
        }
        if spec.extras:
            data["mask"] = _png(tr.valid.astype(np.uint8) * 255, 1)
            data["fit"] = tr.fit_error.astype(np.float32)
        rels = {k: p.as_posix() for k, p in job.paths(Path(), spec.extras).items()}
        info = dict(tr.info)
        rec = {
            "index": job.index,
            "split": job.split,
            "name": job.name,
            "stem": job.stem,
            "source_image": job.image,
            "gyro_segment": info.pop("gyro_segment"),
            "seed": [int(spec.seed), job.index],
            "params": info,
            "files": rels,
        }
        if spec.params.min_blur_px:
            rec["draws_under_min_blur"] = under
        return rec, {rels[k]: v for k, v in data.items()}


def write_files(root: Path, files: dict[str, bytes | np.ndarray], tag: str) -> None:
    """Write a rendered triplet's files under ``root`` (each atomically)."""
    for rel, data in files.items():
        try:
            write_atomic(root / rel, data, tag)
        except BlurTrackError:
            raise  # the atomic writer's one line (OutputError) names the path and the reason
        except OSError as exc:
            raise SynthesisError(f"cannot write {root / rel}: {exc.strerror or exc}") from None


_STATE: dict[str, Any] = {}


def _init_worker(
    spec_dict: dict[str, Any], out: str, tag: str = "s0of1", png_level: int = DEFAULT_PNG_LEVEL
) -> None:
    cv2.setNumThreads(1)
    _STATE.update(renderer=Renderer(spec_dict, png_level), out=Path(out), tag=tag)


def _work(job: Job) -> dict[str, Any]:
    rec, files = _STATE["renderer"].render(job)
    write_files(_STATE["out"], files, _STATE["tag"])
    return rec


def build(
    spec: DatasetSpec,
    out: str | Path,
    shard: tuple[int, int] = (0, 1),
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    png_level: int = DEFAULT_PNG_LEVEL,
) -> BuildResult:
    """Build (or resume) the dataset's triplets of ``shard`` with ``workers`` processes.

    ``progress(done, total)`` is called after each triplet (the CLI draws its bar with it).
    ``png_level`` (0-9) only changes file sizes, never pixels, so it is not part of the spec.
    """
    check_png_level(png_level)
    if not 1 <= workers <= MAX_WORKERS:
        raise SynthesisError(f"workers must be in [1, {MAX_WORKERS}], got {workers}")
    check_synth_size(spec.params, workers)
    with open_build(spec, out, shard, progress) as run:
        run.start()
        if workers <= 1 or len(run.todo) <= 1:
            threads = cv2.getNumThreads()  # in process: leave the caller's OpenCV as it was
            try:
                cv2.setNumThreads(1)
                renderer = Renderer(spec.to_dict(), png_level)
                for job in run.todo:
                    rec, files = renderer.render(job)
                    write_files(run.root, files, run.tag)
                    run.record(rec)
            finally:
                cv2.setNumThreads(threads)
        else:
            ctx = multiprocessing.get_context("spawn")
            init = (spec.to_dict(), str(run.root), run.tag, png_level)
            start = worker_initializer(_init_worker, *init)  # workers end when we die
            with _single_threaded_children(), ctx.Pool(workers, start) as pool:
                for rec in pool.imap_unordered(_work, run.todo):
                    run.record(rec)
    return run.result()


def check_synth_size(params: TripletParams, workers: int) -> None:
    """Refuse triplet sizes and heat-map sampling whose work would need more than half of this
    machine's memory, before anything is allocated (:mod:`blurtrack.io.bounds`)."""
    from blurtrack.io import bounds

    w, h = params.size
    if w < 1 or h < 1:
        raise SynthesisError(f"--size must be positive, got {w}x{h}")
    bounds.check_synth_size(w, h, workers)
    bounds.check_prediction_size(w, h, max(1, params.heat_stride), params.heat_n_t, "synth")


def check_png_level(level: int) -> None:
    if not 0 <= level <= 9:
        raise SynthesisError(f"PNG compression level must be in [0, 9], got {level}")


#: Thread-pool variables of numpy's BLAS back ends; each worker is one process on one core.
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    """Spawned workers start with one BLAS thread each (they read the variables at start-up);
    the parent's environment is restored afterwards."""
    saved = {k: os.environ.get(k) for k in _THREAD_VARS}
    os.environ.update({k: "1" for k in _THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
