"""A dataset build in progress: the inputs checked, the dataset lock, ``dataset.yaml``
checked or written, the manifest repaired and the jobs left (:func:`open_build`), and what the
build did (:class:`BuildResult`). Shared by the one-machine build
(:func:`blurtrack.synth.dataset.build`) and the cluster's (:mod:`blurtrack.synth.cluster`)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.io.yamlio import read_yaml, write_yaml
from blurtrack.synth.images import list_images
from blurtrack.synth.motion import open_source
from blurtrack.synth.spec import FORMAT, DatasetSpec, Job, plan
from blurtrack.synth.store import (
    ManifestWriter,
    dataset_lock,
    finished,
    input_identity,
    read_manifest,
    remove_temporaries,
)


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
