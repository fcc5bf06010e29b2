"""The training-triplet dataset: plan, parallel build, resume, shards and merge.

Layout (COMMON "Shared formats", GoPro style)::

    DATASET/dataset.yaml                        format: blurtrack-dataset/1 + the full spec
    DATASET/manifest.jsonl                      one JSON object per triplet (sorted by index)
    DATASET/manifest-shard<I>.jsonl             per-shard manifests before ``merge``
    DATASET/{train,test}/<name>/sharp/<stem>.png   8-bit sRGB
    DATASET/{train,test}/<name>/blur/<stem>.png
    DATASET/{train,test}/<name>/heat/<stem>.npy    float32 (6, H, W)

Triplet ``i`` is fully determined by ``(spec, i)``: its image is ``images[perm[i % n]]`` with a
seeded permutation, its randomness comes from ``SeedSequence([seed, i])``. Files are written to a
hidden temporary name and renamed into place, and the manifest line is appended (and fsynced)
only after all three files are in place, so a killed build leaves only finished triplets under
final names; a rerun skips every triplet whose manifest line and files exist. Shard ``I/N``
builds the indices ``i % N == I`` into ``manifest-shardI.jsonl``; shards built on separate
machines are combined with :func:`merge`.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError, SynthesisError
from blurtrack.io import atomic
from blurtrack.io.calibration import Calibration
from blurtrack.io.yamlio import read_yaml, write_text_atomic, write_yaml
from blurtrack.synth.images import list_images, load_image, split_of
from blurtrack.synth.motion import open_source
from blurtrack.synth.triplet import TripletParams, make_triplet, triplet_rng

FORMAT = "blurtrack-dataset/1"
KINDS = (("sharp", ".png"), ("blur", ".png"), ("heat", ".npy"))
#: Optional extra files (``extras=True``): validity mask (0/255 PNG) and Bezier fit error (px).
EXTRA_KINDS = (("mask", ".png"), ("fit", ".npy"))
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
        Calibration.from_dict(self.calib)  # validates

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


def read_manifest(path: Path, repair: bool = False) -> dict[int, dict[str, Any]]:
    """Records by index (a later line wins). A final line without newline is the trace of a
    killed writer: ignored, and cut off when ``repair``. Any other bad line is an error."""
    if not path.is_file():
        return {}
    raw = path.read_bytes()
    end = raw.rfind(b"\n") + 1
    if end < len(raw) and repair:
        with path.open("r+b") as f:
            f.truncate(end)
    records: dict[int, dict[str, Any]] = {}
    for n, line in enumerate(raw[:end].splitlines(), start=1):
        try:
            rec = json.loads(line)
            records[int(rec["index"])] = rec
        except (ValueError, KeyError, TypeError):
            raise SynthesisError(f"{path}: line {n} is not a manifest record") from None
    return records


def _write_atomic(path: Path, data: bytes | np.ndarray, tag: str = "x") -> None:
    """Write ``data`` (bytes, or an array as ``.npy``, streamed without an in-memory copy) to a
    hidden ``.<name>.<tag>.<random>.tmp`` file, then rename it to ``path``
    (:mod:`blurtrack.io.atomic`).

    ``tag`` names the shard, so a shard cleaning up after a killed run of itself never
    touches the temporaries of another shard running in the same folder.
    """
    if isinstance(data, np.ndarray):
        atomic.write_atomic(path, lambda f: np.save(f, data, allow_pickle=False), tag)
    else:
        atomic.write_bytes_atomic(path, data, tag)


def _png(img: np.ndarray, level: int = 0) -> bytes:
    flags = [cv2.IMWRITE_PNG_COMPRESSION, int(level)]
    if level == 0:  # row filters only help deflate; unfiltered stored PNG encodes 4x faster
        flags += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", img, flags)
    if not ok:
        raise SynthesisError("PNG encoding failed")
    return buf.tobytes()


# ------------------------------------------------------------------ worker side
_STATE: dict[str, Any] = {}


def _init_worker(
    spec_dict: dict[str, Any], out: str, tag: str = "s0of1", png_level: int = DEFAULT_PNG_LEVEL
) -> None:
    cv2.setNumThreads(1)
    spec = DatasetSpec.from_dict(spec_dict)
    _STATE.update(
        spec=spec,
        out=Path(out),
        tag=tag,
        png=png_level,
        calib=Calibration.from_dict(spec.calib),
        source=open_source(spec.gyro),
    )


def _work(job: Job) -> dict[str, Any]:
    spec: DatasetSpec = _STATE["spec"]
    out: Path = _STATE["out"]
    try:
        image = load_image(spec.images, job.image)
        tr = make_triplet(
            image, _STATE["calib"], _STATE["source"], spec.params, triplet_rng(spec.seed, job.index)
        )
    except BlurTrackError as exc:
        raise SynthesisError(f"triplet {job.index} ({job.image}): {exc}") from None
    paths = job.paths(out, spec.extras)
    tag = _STATE["tag"]
    _write_atomic(paths["sharp"], _png(tr.sharp, _STATE["png"]), tag)
    _write_atomic(paths["blur"], _png(tr.blur, _STATE["png"]), tag)
    _write_atomic(paths["heat"], tr.heat, tag)
    if spec.extras:
        _write_atomic(paths["mask"], _png(tr.valid.astype(np.uint8) * 255, 1), tag)
        _write_atomic(paths["fit"], tr.fit_error.astype(np.float32), tag)
    info = dict(tr.info)
    return {
        "index": job.index,
        "split": job.split,
        "name": job.name,
        "stem": job.stem,
        "source_image": job.image,
        "gyro_segment": info.pop("gyro_segment"),
        "seed": [int(spec.seed), job.index],
        "params": info,
        "files": {k: p.relative_to(out).as_posix() for k, p in paths.items()},
    }


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

    def to_dict(self) -> dict[str, Any]:
        rate = self.made / self.elapsed_s if self.elapsed_s > 0 else None
        return {
            "made": self.made,
            "skipped": self.skipped,
            "planned": self.planned,
            "elapsed_s": self.elapsed_s,
            "triplets_per_s": rate,
            "manifest": self.manifest.name,
            "bezier_fit_within_0.5px_min": self.fit_share_min,
            "bezier_fit_within_0.5px_mean": self.fit_share_mean,
        }


def _check_spec(out: Path, spec: DatasetSpec) -> None:
    path = out / "dataset.yaml"
    want = {"format": FORMAT, "spec": spec.to_dict()}
    if path.is_file():
        have = read_yaml(path, "dataset.yaml")
        if have != json.loads(json.dumps(want)):
            raise SynthesisError(
                f"{out} holds a dataset made with other parameters; use a new "
                f"--out or the same options"
            )
    else:
        write_yaml(path, want)


def _inside(out: Path, rel: Any) -> bool:
    """Whether ``rel`` names an existing file inside ``out`` (manifests are untrusted)."""
    if not isinstance(rel, str) or not rel or Path(rel).is_absolute() or ".." in Path(rel).parts:
        return False
    return (out / rel).is_file()


def _finished(out: Path, records: dict[int, dict[str, Any]]) -> set[int]:
    done = set()
    for i, rec in records.items():
        files = rec.get("files", {})
        if all(_inside(out, files.get(k)) for k, _ in KINDS) and all(
            _inside(out, f) for f in files.values()
        ):
            done.add(i)
    return done


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
    t0 = time.perf_counter()
    if not 0 <= png_level <= 9:
        raise SynthesisError(f"PNG compression level must be in [0, 9], got {png_level}")
    if not 1 <= workers <= MAX_WORKERS:
        raise SynthesisError(f"workers must be in [1, {MAX_WORKERS}], got {workers}")
    root = Path(out)
    if root.resolve().is_relative_to(Path(spec.images).resolve()):
        raise SynthesisError(
            f"the dataset folder {root} must not lie inside the image folder "
            f"{spec.images} (its images would become inputs)"
        )
    images = list_images(spec.images)  # inputs first: a bad one leaves no folder behind
    source = open_source(spec.gyro)
    root.mkdir(parents=True, exist_ok=True)
    _check_spec(root, spec)
    k, n = shard
    mine = [j for j in plan(spec, images, source.tag) if j.index % n == k]
    manifest = root / ("manifest.jsonl" if n == 1 else f"manifest-shard{k}.jsonl")
    records = {**read_manifest(root / "manifest.jsonl"), **read_manifest(manifest, repair=True)}
    done = _finished(root, records)
    todo = [j for j in mine if j.index not in done]
    tag = f"s{k}of{n}"
    for tmp in root.glob(f"*/*/*/.*.{tag}.*.tmp"):  # this shard's leftovers of a killed run
        tmp.unlink(missing_ok=True)
    made, fits = 0, []
    with manifest.open("a", encoding="utf-8") as f:

        def record(rec: dict[str, Any]) -> None:
            nonlocal made
            f.write(json.dumps(rec, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
            made += 1
            fits.append(rec["params"]["bezier_fit"]["within_0.5px"])
            if progress:
                progress(made, len(todo))

        if progress:
            progress(0, len(todo))
        if workers <= 1 or len(todo) <= 1:
            threads = cv2.getNumThreads()  # in process: leave the caller's OpenCV as it was
            try:
                _init_worker(spec.to_dict(), str(root), tag, png_level)
                for job in todo:
                    record(_work(job))
            finally:
                cv2.setNumThreads(threads)
                _STATE.clear()
        else:
            ctx = multiprocessing.get_context("spawn")
            init = (spec.to_dict(), str(root), tag, png_level)
            with _single_threaded_children(), ctx.Pool(workers, _init_worker, init) as pool:
                for rec in pool.imap_unordered(_work, todo):
                    record(rec)
    return BuildResult(
        made,
        len(mine) - len(todo),
        len(mine),
        time.perf_counter() - t0,
        manifest,
        min(fits) if fits else None,
        float(np.mean(fits)) if fits else None,
    )


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


def _move(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(src, dst)
    except OSError:  # another file system: copy to a temporary name, then rename
        with atomic.atomic_path(dst) as tmp:
            shutil.copy2(src, tmp)


def _portable(d: Any) -> Any:
    """A dataset.yaml with its input paths cut to their last component: shards made on other
    machines see the same inputs under other mount points."""
    if not isinstance(d, dict) or not isinstance(d.get("spec"), dict):
        raise SynthesisError("dataset.yaml lacks its spec")
    spec = dict(d["spec"])
    for k in ("images", "gyro"):
        spec[k] = Path(str(spec.get(k, ""))).name
    return {**d, "spec": spec}


def merge(out: str | Path, shard_dirs: Iterable[str | Path] = ()) -> dict[str, Any]:
    """Combine shard manifests (in ``out`` and in ``shard_dirs``, whose files are moved into
    ``out``) into one sorted ``manifest.jsonl``; returns a summary with missing indices."""
    root = Path(out)
    dirs = [Path(d) for d in shard_dirs]
    ref = key = None
    for d in [root, *dirs]:
        if (d / "dataset.yaml").is_file():
            have = read_yaml(d / "dataset.yaml", "dataset.yaml")
            if key is not None and _portable(have) != key:
                raise SynthesisError(f"{d} was built with other parameters than the others")
            ref, key = have, _portable(have)
    if ref is None:
        raise SynthesisError("no dataset.yaml found in the merged folders")
    root.mkdir(parents=True, exist_ok=True)
    if not (root / "dataset.yaml").is_file():
        write_yaml(root / "dataset.yaml", ref)
    records = read_manifest(root / "manifest.jsonl")
    consumed = sorted(root.glob("manifest-shard*.jsonl"))
    for m in consumed:
        records.update(read_manifest(m))
    for d in dirs:
        if d.resolve() == root.resolve():
            continue
        for m in sorted([*d.glob("manifest-shard*.jsonl"), d / "manifest.jsonl"]):
            for i, rec in read_manifest(m).items():
                for rel in rec.get("files", {}).values():
                    if _inside(d, rel):
                        _move(d / rel, root / rel)
                records[i] = rec
    done = _finished(root, records)
    lines = "".join(json.dumps(records[i], sort_keys=True) + "\n" for i in sorted(done))
    write_text_atomic(root / "manifest.jsonl", lines)
    for m in consumed:
        m.unlink()
    count = int(ref["spec"]["count"])
    missing = sorted(set(range(count)) - done)
    return {
        "triplets": len(done),
        "count": count,
        "missing": len(missing),
        "missing_first": missing[:20],
        "lost_records": len(records) - len(done),
    }
