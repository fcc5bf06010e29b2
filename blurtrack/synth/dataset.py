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
:mod:`blurtrack.synth.store`). Shard ``I/N`` builds the indices ``i % N == I`` into
``manifest-shardI.jsonl``; shards are combined by :func:`blurtrack.synth.merge.merge`. The
same build runs on a Dask cluster through :mod:`blurtrack.synth.cluster`, which shares
:func:`open_build` and :class:`Renderer` with this module.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError, SynthesisError
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.yamlio import read_yaml, write_yaml
from blurtrack.synth.images import list_images, load_image, split_of
from blurtrack.synth.motion import open_source
from blurtrack.synth.store import (
    EXTRA_KINDS,
    KINDS,
    ManifestWriter,
    dataset_lock,
    finished,
    input_identity,
    read_manifest,
    remove_temporaries,
    write_atomic,
)
from blurtrack.synth.triplet import TripletParams, draw_triplet
from blurtrack.workers import worker_initializer

__all__ = ["DatasetSpec", "build", "open_build", "read_manifest"]

FORMAT = "blurtrack-dataset/1"
#: Largest dataset (triplets) and worker count accepted.
MAX_COUNT = 1_000_000
MAX_WORKERS = 64
#: PNG deflate level of sharp and blurred images. 0 (stored) encodes about twice as fast as 1
#: and costs ~1.5 MB per 1280x720 image, small next to the 22 MB of its heat maps.
DEFAULT_PNG_LEVEL = 0


@dataclass(frozen=True)
class DatasetSpec:
    """What a dataset is made of; stored in ``dataset.yaml`` and checked on resume/merge."""

    calib: dict[str, Any]
    gyro: str
    images: str
    count: int
    seed: int
    params: TripletParams
    group: int = 100
    extras: bool = False

    def __post_init__(self) -> None:
        if not 1 <= int(self.count) <= MAX_COUNT or int(self.group) < 1:
            raise SynthesisError(
                f"count must be in [1, {MAX_COUNT}] and group >= 1, got {self.count}"
            )
        calibration_from_dict(self.calib)  # validates

    def to_dict(self) -> dict[str, Any]:
        return {
            "calib": self.calib,
            "gyro": self.gyro,
            "images": self.images,
            "count": int(self.count),
            "seed": int(self.seed),
            "group": int(self.group),
            "extras": bool(self.extras),
            "params": self.params.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DatasetSpec:
        try:
            return cls(**{**d, "params": TripletParams.from_dict(d["params"])})
        except (KeyError, TypeError) as exc:
            raise SynthesisError(f"dataset.yaml spec is malformed: {exc}") from None


@dataclass(frozen=True)
class Job:
    index: int
    split: str
    name: str
    stem: str
    image: str

    def paths(self, out: Path, extras: bool = False) -> dict[str, Path]:
        base = out / self.split / self.name
        kinds = KINDS + (EXTRA_KINDS if extras else ())
        return {k: base / k / f"{self.stem}{ext}" for k, ext in kinds}


def plan(spec: DatasetSpec, images: list[str], tag: str) -> list[Job]:
    """Every triplet of the dataset, in index order."""
    perm = np.random.default_rng(np.random.SeedSequence([int(spec.seed), 2**32 - 1])).permutation(
        len(images)
    )
    jobs = []
    for i in range(int(spec.count)):
        img = images[int(perm[i % len(images)])]
        jobs.append(Job(i, split_of(img), f"{tag}_{i // spec.group:04d}", f"{i:06d}", img))
    return jobs


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` -> ``(I, N)`` with ``0 <= I < N``."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise SynthesisError(f"--shard must be I/N, got {text!r}") from None
    if not 0 <= i < n:
        raise SynthesisError(f"--shard I/N needs 0 <= I < N, got {text!r}")
    return i, n


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


# ------------------------------------------------------------------ builder side
@dataclass(frozen=True)
class BuildResult:
    """What a build did: counts, timing, where the manifest is, fit statistics."""

    made: int
    skipped: int
    planned: int
    elapsed_s: float
    manifest: Path
    fit_share_min: float | None
    fit_share_mean: float | None = None
    #: Draws whose median blur fell under ``min_blur_px`` and were drawn again, over the
    #: triplets made now and over all finished triplets of this shard (resumed runs too).
    under_min_blur: int = 0
    under_min_blur_total: int = 0
    min_blur_px: float = 0.0
    #: Finished triplets whose files were zero-byte, truncated or undecodable: made again.
    remade_broken: tuple[int, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        rate = self.made / self.elapsed_s if self.elapsed_s > 0 else None
        return {
            "min_blur_px": self.min_blur_px,
            "draws_under_min_blur": self.under_min_blur,
            "draws_under_min_blur_total": self.under_min_blur_total,
            "made": self.made,
            "skipped": self.skipped,
            "planned": self.planned,
            "elapsed_s": self.elapsed_s,
            "triplets_per_s": rate,
            "manifest": self.manifest.name,
            "bezier_fit_within_0.5px_min": self.fit_share_min,
            "bezier_fit_within_0.5px_mean": self.fit_share_mean,
            "remade_broken": list(self.remade_broken),
        }


def _check_spec(out: Path, spec: DatasetSpec, identity: str) -> None:
    path = out / "dataset.yaml"
    want = json.loads(json.dumps({"format": FORMAT, "identity": identity, "spec": spec.to_dict()}))
    if not path.is_file():
        write_yaml(path, want)
        return
    have = read_yaml(path, "dataset.yaml")
    if have == want:
        return
    if isinstance(have, dict) and {**have, "identity": identity} == want:
        raise SynthesisError(
            f"{out} holds a dataset made from other inputs (photos or gyro data differ from "
            f"{spec.images} / {spec.gyro}); use a new --out or the original inputs"
        )
    raise SynthesisError(
        f"{out} holds a dataset made with other parameters; use a new --out or the same options"
    )


@dataclass
class BuildRun:
    """A build in progress (from :func:`open_build`): the jobs left and the manifest writer;
    :meth:`record` appends a finished triplet."""

    spec: DatasetSpec
    root: Path
    tag: str
    identity: str
    mine: list[Job]
    todo: list[Job]
    manifest: Path
    progress: Callable[[int, int], None] | None
    writer: ManifestWriter
    t0: float
    fits: list[float] = field(default_factory=list)
    under: int = 0
    under_before: int = 0
    broken: tuple[int, ...] = ()

    def start(self) -> None:
        """Report the work about to start (``progress(0, jobs left)``)."""
        if self.progress:
            self.progress(0, len(self.todo))

    def record(self, rec: dict[str, Any]) -> None:
        self.writer.append(rec)
        self.fits.append(rec["params"]["bezier_fit"]["within_0.5px"])
        self.under += int(rec.get("draws_under_min_blur", 0))
        if self.progress:
            self.progress(len(self.fits), len(self.todo))

    def result(self) -> BuildResult:
        fits = self.fits
        return BuildResult(
            len(fits),
            len(self.mine) - len(self.todo),
            len(self.mine),
            time.perf_counter() - self.t0,
            self.manifest,
            min(fits) if fits else None,
            float(np.mean(fits)) if fits else None,
            self.under,
            self.under_before + self.under,
            float(self.spec.params.min_blur_px),
            self.broken,
        )


def inputs_identity(spec: DatasetSpec, images: list[str], gyro_fingerprint: str) -> str:
    """The identity of ``spec`` built from ``images`` and that gyro (see :mod:`store`)."""
    return input_identity(spec.to_dict(), Path(spec.images), images, gyro_fingerprint)


@contextlib.contextmanager
def open_build(
    spec: DatasetSpec,
    out: str | Path,
    shard: tuple[int, int] = (0, 1),
    progress: Callable[[int, int], None] | None = None,
) -> Iterator[BuildRun]:
    """Check the inputs, take the dataset lock, check or write ``dataset.yaml``, repair the
    manifest, list the jobs left, and yield the run; the lock is held until the block ends."""
    t0 = time.perf_counter()
    root = Path(out)
    if root.resolve().is_relative_to(Path(spec.images).resolve()):
        raise SynthesisError(
            f"the dataset folder {root} must not lie inside the image folder "
            f"{spec.images} (its images would become inputs)"
        )
    images = list_images(spec.images)  # inputs first: a bad one leaves no folder behind
    source = open_source(spec.gyro)
    identity = inputs_identity(spec, images, source.fingerprint())
    k, n = shard
    name = "manifest.jsonl" if n == 1 else f"manifest-shard{k}.jsonl"
    root.mkdir(parents=True, exist_ok=True)
    with dataset_lock(root, None if n == 1 else name):
        _check_spec(root, spec, identity)
        mine = [j for j in plan(spec, images, source.tag) if j.index % n == k]
        manifest = root / name
        records = {**read_manifest(root / "manifest.jsonl"), **read_manifest(manifest, True)}
        broken: set[int] = set()
        done = finished(root, records, spec.count, spec.group, spec.extras, broken)
        todo = [j for j in mine if j.index not in done]
        tag = f"s{k}of{n}"
        remove_temporaries(root, tag)  # this shard's leftovers of a killed run
        writer = ManifestWriter(manifest)
        run = BuildRun(spec, root, tag, identity, mine, todo, manifest, progress, writer, t0)
        run.broken = tuple(sorted(j.index for j in mine if j.index in broken))
        run.under_before = sum(
            int(records[j.index].get("draws_under_min_blur", 0)) for j in mine if j.index in done
        )
        try:
            yield run
        finally:
            writer.close()


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
