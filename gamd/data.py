"""Datasets made by ``blurtrack synth`` (and GoPro-layout folders) for training and evaluation.

Layout (COMMON "Shared formats"): ``ROOT/<split>/<name>/{sharp,blur}/<stem>.png`` (8-bit sRGB
RGB) and, for synthesised sets, ``ROOT/<split>/<name>/heat/<stem>.npy`` (``(6, H, W)`` float32,
pixels). GoPro has the same layout without ``heat/``; networks that need heat maps refuse it.

Training samples are addressed by ``(index, seed)`` keys: the crop position and the
flips/rotation come from ``seed`` alone, and :class:`StepBatchSampler` derives every key from
``(run seed, step, slot)``. The data a step sees therefore does not depend on how the run was
interrupted or on the number of loader workers, which makes resume exact.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from blurtrack.io.images import ImageError, read_image
from gamd.errors import GamdDataError
from gamd.heat import DEFAULT_HEAT_SCALE_PX, augment, normalise_heat
from gamd.restorer import check_restore_options, recentre, to_working, working_scale

#: Refuse images larger than this many pixels (a corrupt header must not exhaust memory).
MAX_PIXELS = 64_000_000


@dataclass(frozen=True)
class TripletFiles:
    """Paths of one (blur, sharp, heat) example; ``heat`` is None in GoPro-style sets."""

    name: str
    blur: Path
    sharp: Path | None
    heat: Path | None


def read_rgb(path: Path) -> np.ndarray:
    """Read an image as float32 RGB ``(H, W, 3)`` in [0, 1] (8- or 16-bit, gray or colour)."""
    try:
        img = read_image(path)
    except ImageError as exc:
        raise GamdDataError(str(exc)) from None
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    else:
        raise GamdDataError(f"{path}: unsupported channel count {img.shape[2]}")
    if img.shape[0] * img.shape[1] > MAX_PIXELS:
        raise GamdDataError(f"{path}: image too large {img.shape[:2]}")
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(img.dtype)
    if scale is None:
        raise GamdDataError(f"{path}: unsupported pixel type {img.dtype}")
    return img.astype(np.float32) / scale


def read_heat(path: Path, shape_hw: tuple[int, int]) -> np.ndarray:
    """Read a ``(6, H, W)`` float32 heat map and check it against the image size."""
    try:
        heat = np.load(path, allow_pickle=False, mmap_mode="r")
    except (OSError, ValueError) as exc:
        raise GamdDataError(f"cannot read heat map {path}: {exc}") from exc
    if heat.shape != (6, *shape_hw):
        raise GamdDataError(f"{path}: heat map shape {heat.shape}, expected {(6, *shape_hw)}")
    heat = np.array(heat, dtype=np.float32)  # a writable copy
    if not np.isfinite(heat).all():
        raise GamdDataError(f"{path}: heat map contains NaN or inf")
    return heat


def find_triplets(
    root: Path, split: str, need_sharp: bool = True, heat_root: Path | None = None
) -> list[TripletFiles]:
    """All triplets of ``root/split`` in sorted order; heat maps from ``heat_root`` (same
    layout) instead of ``root`` when given (e.g. heat maps of a perturbed calibration)."""
    base = Path(root) / split
    if not base.is_dir():
        raise GamdDataError(f"dataset split folder not found: {base}")
    triplets = []
    for blur in sorted(base.glob("*/blur/*.png")):
        group = blur.parent.parent
        sharp = group / "sharp" / blur.name
        heat_group = group if heat_root is None else Path(heat_root) / split / group.name
        heat = heat_group / "heat" / (blur.stem + ".npy")
        if need_sharp and not sharp.is_file():
            raise GamdDataError(f"missing sharp image for {blur}")
        triplets.append(
            TripletFiles(
                name=f"{group.name}/{blur.stem}",
                blur=blur,
                sharp=sharp if sharp.is_file() else None,
                heat=heat if heat.is_file() else None,
            )
        )
    if not triplets:
        raise GamdDataError(f"no <name>/blur/*.png images under {base}")
    return triplets


def to_tensor(img_hwc: np.ndarray) -> torch.Tensor:
    """``(H, W, C)`` float array -> ``(C, H, W)`` tensor."""
    return torch.from_numpy(np.ascontiguousarray(img_hwc.transpose(2, 0, 1)))


class DeblurDataset(Dataset):
    """Blur/sharp/heat examples of one split.

    ``dataset[(index, seed)]`` gives a random crop (``crop × crop``) with random flips and
    quarter turns (if ``augment``); ``dataset.full(index)`` gives the whole image unchanged.
    Items are dicts: ``blur``, ``sharp`` ``(3, h, w)`` in [0, 1], ``heat`` ``(6, h, w)``
    normalised (zeros when the set has no heat maps and ``require_heat`` is False), ``index``.
    With ``work_blur_px``, training items are first brought to the working resolution of
    :mod:`gamd.restorer` (blur of about ``work_blur_px``), then cropped. With ``recentre``
    (default), training items are first recentred as inference does
    (:func:`gamd.restorer.recentre`: rolling-shutter blur resampled to the reference view; a
    no-op for global-shutter triplets and sets without heat maps). ``full`` never recentres.
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        crop: int | None = 128,
        augment: bool = True,
        heat_scale_px: float = DEFAULT_HEAT_SCALE_PX,
        require_heat: bool = True,
        heat_root: str | Path | None = None,
        work_blur_px: float | None = None,
        recentre: bool = True,
    ) -> None:
        if crop is not None and (not isinstance(crop, int) or crop < 8 or crop % 4):
            raise GamdDataError(f"crop must be a multiple of 4 >= 8, got {crop!r}")
        self.root, self.split, self.crop = Path(root), split, crop
        self.augment, self.heat_scale_px, self.require_heat = augment, heat_scale_px, require_heat
        self.work_blur_px, self.recentre = work_blur_px, recentre
        if work_blur_px is not None:
            check_restore_options(heat_scale_px, work_blur_px, None)
            self.require_heat = True
        self.triplets = find_triplets(
            self.root, split, heat_root=None if heat_root is None else Path(heat_root)
        )
        missing = [t.name for t in self.triplets if t.heat is None]
        if self.require_heat and missing:
            raise GamdDataError(
                f"{len(missing)} examples of {self.root / split} have no heat "
                f"map (first: {missing[0]}); this network needs them"
            )

    def __len__(self) -> int:
        return len(self.triplets)

    def _load(self, index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        t = self.triplets[index]
        blur = read_rgb(t.blur)
        sharp = read_rgb(t.sharp) if t.sharp is not None else None
        if sharp is None or sharp.shape != blur.shape:
            raise GamdDataError(f"{t.name}: sharp image missing or of another size than blur")
        hw = blur.shape[:2]
        if t.heat is not None:
            heat = normalise_heat(torch.from_numpy(read_heat(t.heat, hw)), self.heat_scale_px)
        else:
            heat = torch.zeros((6, *hw), dtype=torch.float32)
        return to_tensor(blur), to_tensor(sharp), heat

    def full(self, index: int) -> dict:
        """The whole example, without crop or augmentation."""
        blur, sharp, heat = self._load(index)
        return {"blur": blur, "sharp": sharp, "heat": heat, "index": index}

    def __getitem__(self, key: tuple[int, int]) -> dict:
        index, seed = key
        blur, sharp, heat = self._load(index)
        rng = np.random.default_rng(seed)
        h, w = blur.shape[-2:]
        if self.recentre and self.triplets[index].heat is not None:  # as inference does
            (b,), hp = recentre([blur[None]], heat[None] * self.heat_scale_px)
            blur, heat = b[0], hp[0] / self.heat_scale_px
        if self.work_blur_px is not None:  # the working resolution inference will use
            heat_px = heat[None] * self.heat_scale_px
            limit = min(h, w) / self.crop if self.crop is not None else math.inf
            scale = working_scale(heat_px[0], self.work_blur_px, limit)
            (b, s), hp = to_working([blur[None], sharp[None]], heat_px, scale)
            blur, sharp, heat = b[0], s[0], hp[0] / self.heat_scale_px
            h, w = blur.shape[-2:]
        if self.crop is not None:
            if h < self.crop or w < self.crop:
                raise GamdDataError(
                    f"{self.triplets[index].name}: image {w}x{h} smaller than crop {self.crop}"
                )
            y0 = int(rng.integers(0, h - self.crop + 1))
            x0 = int(rng.integers(0, w - self.crop + 1))
            sl = (slice(None), slice(y0, y0 + self.crop), slice(x0, x0 + self.crop))
            blur, sharp, heat = blur[sl], sharp[sl], heat[sl]
        if self.augment:
            flip_h, flip_v = bool(rng.integers(2)), bool(rng.integers(2))
            square = blur.shape[-1] == blur.shape[-2]
            turns = int(rng.integers(4)) if square else 2 * int(rng.integers(2))
            (blur, sharp), heat_aug = augment([blur, sharp], heat, flip_h, flip_v, turns)
            assert heat_aug is not None  # augment returns heat maps when given some
            heat = heat_aug
        return {
            "blur": blur.contiguous(),
            "sharp": sharp.contiguous(),
            "heat": heat.contiguous(),
            "index": index,
        }


class StepBatchSampler(Sampler[list[tuple[int, int]]]):
    """Batches of ``(index, seed)`` keys for steps ``start_step .. steps - 1``.

    The global batch of step ``s`` holds ``batch_size × world_size`` slots filled from
    successive seeded permutations of the dataset (one per epoch); rank ``r`` takes slots
    ``r·batch_size .. (r+1)·batch_size - 1``. Each slot's augmentation seed is derived from
    ``(seed, s, slot)``.
    """

    def __init__(
        self,
        num_items: int,
        batch_size: int,
        steps: int,
        seed: int,
        start_step: int = 0,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        if num_items < 1 or batch_size < 1 or world_size < 1 or not 0 <= rank < world_size:
            raise GamdDataError("invalid sampler arguments")
        self.n, self.bs, self.steps, self.seed = num_items, batch_size, steps, seed
        self.start, self.rank, self.world = start_step, rank, world_size
        self._perm_cache: dict[int, np.ndarray] = {}

    def _perm(self, epoch: int) -> np.ndarray:
        if epoch not in self._perm_cache:
            self._perm_cache = {
                epoch: np.random.default_rng([self.seed, epoch]).permutation(self.n)
            }
        return self._perm_cache[epoch]

    def batch(self, step: int) -> list[tuple[int, int]]:
        """This rank's keys of ``step``."""
        per_step = self.bs * self.world
        keys = []
        for slot in range(self.rank * self.bs, (self.rank + 1) * self.bs):
            pos = step * per_step + slot
            index = int(self._perm(pos // self.n)[pos % self.n])
            item_seed = int(np.random.SeedSequence([self.seed, step, slot]).generate_state(1)[0])
            keys.append((index, item_seed))
        return keys

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        for step in range(self.start, self.steps):
            yield self.batch(step)

    def __len__(self) -> int:
        return max(0, self.steps - self.start)
