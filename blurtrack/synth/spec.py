"""What a training-triplet dataset is made of (``dataset.yaml``'s spec) and its plan: every
triplet's image, split, group and name, fully determined by the spec
(:mod:`blurtrack.synth.dataset`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.synth.images import split_of
from blurtrack.synth.store import EXTRA_KINDS, KINDS
from blurtrack.synth.triplet import TripletParams

FORMAT = "blurtrack-dataset/1"
#: Largest dataset (triplets) accepted.
MAX_COUNT = 1_000_000


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
