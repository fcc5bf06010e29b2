"""Dataset reading, crops, heat-consistent augmentation and the step sampler."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gamd.data import DeblurDataset, StepBatchSampler, find_triplets, read_heat
from gamd.errors import GamdDataError
from gamd.heat import augment, hflip, normalise_heat, rot90, vflip


def _ramp_heat(h: int, w: int) -> np.ndarray:
    """A spatially varying motion: q grows along x and y."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    base = [2.5, -1.0, -2.0, 1.5, 0.5, 2.0]
    return np.stack([b + 0.04 * (xs if i % 2 == 0 else ys) for i, b in enumerate(base)]).astype(
        np.float32
    )


@pytest.mark.parametrize("op", ["h", "v", "r1", "r2", "r3", "hr1"])
def test_augmented_heat_reproduces_augmented_blur(op: str, blur_fn) -> None:
    rng = np.random.default_rng(3)
    h = w = 40
    sharp = np.clip(rng.random((h, w, 3)), 0, 1).astype(np.float32)
    heat = _ramp_heat(h, w)
    blur = blur_fn(sharp, heat)
    s_t = torch.from_numpy(sharp.transpose(2, 0, 1).copy())
    b_t = torch.from_numpy(blur.transpose(2, 0, 1).copy())
    h_t = torch.from_numpy(heat)
    flip_h = op.startswith("h")
    flip_v = op == "v"
    turns = int(op[-1]) if "r" in op else 0
    (s_a, b_a), h_a = augment([s_t, b_t], h_t, flip_h, flip_v, turns)
    reblur = blur_fn(s_a.numpy().transpose(1, 2, 0).copy(), h_a.numpy())
    m = 8  # away from the reflected border
    err = np.abs(reblur - b_a.numpy().transpose(1, 2, 0))[m:-m, m:-m]
    assert err.max() < 1e-4
    # a wrong sign would not reproduce it: the check has teeth
    wrong = h_a.clone()
    wrong[[0, 2, 4]] *= -1
    bad = blur_fn(s_a.numpy().transpose(1, 2, 0).copy(), wrong.numpy())
    assert np.abs(bad - b_a.numpy().transpose(1, 2, 0))[m:-m, m:-m].max() > 1e-2


def test_flip_and_rotation_inverses() -> None:
    img, heat = torch.rand(3, 6, 6), torch.randn(6, 6, 6)
    for fn in (hflip, vflip):
        i2, h2 = fn(*fn(img, heat))
        assert torch.equal(i2, img) and torch.equal(h2, heat)
    i4, h4 = img, heat
    for _ in range(4):
        i4, h4 = rot90(i4, h4, 1)
    assert torch.equal(i4, img) and torch.equal(h4, heat)
    i3, h3 = rot90(img, heat, 3)
    i1, h1 = rot90(*rot90(*rot90(img, heat, 1), 1), 1)
    assert torch.equal(i3, i1) and torch.equal(h3, h1)


def test_dataset_reads_layout_crops_and_normalises(tiny_dataset) -> None:
    ds = DeblurDataset(tiny_dataset, "train", crop=32, augment=False, heat_scale_px=4.0)
    assert len(ds) == 6
    full = ds.full(0)
    assert full["blur"].shape == (3, 40, 48) and full["heat"].shape == (6, 40, 48)
    raw = np.load(ds.triplets[0].heat)
    assert torch.allclose(full["heat"], torch.from_numpy(raw) / 4.0)
    item = ds[(0, 123)]
    assert item["blur"].shape == (3, 32, 32) and item["heat"].shape == (6, 32, 32)
    assert float(item["blur"].min()) >= 0.0 and float(item["blur"].max()) <= 1.0
    assert torch.equal(ds[(0, 123)]["blur"], item["blur"])  # keys are deterministic
    aug = DeblurDataset(tiny_dataset, "train", crop=32, augment=True)
    seen = {tuple(aug[(1, s)]["heat"][:, 0, 0].sign().tolist()) for s in range(24)}
    assert len(seen) > 1  # flips/rotations change the heat signs


def test_dataset_failures(tiny_dataset, tmp_path, make_dataset) -> None:
    with pytest.raises(GamdDataError, match="not found"):
        DeblurDataset(tmp_path / "nope", "train")
    with pytest.raises(GamdDataError, match="smaller than crop"):
        DeblurDataset(tiny_dataset, "train", crop=64)[(0, 0)]
    with pytest.raises(GamdDataError, match="crop"):
        DeblurDataset(tiny_dataset, "train", crop=30)
    gopro = make_dataset(tmp_path / "gopro", {"train": 2}, with_heat=False)
    with pytest.raises(GamdDataError, match="no heat"):
        DeblurDataset(gopro, "train")
    ds = DeblurDataset(gopro, "train", require_heat=False, crop=None, augment=False)
    assert float(ds.full(0)["heat"].abs().sum()) == 0.0
    bad = tmp_path / "bad.npy"
    np.save(bad, np.full((6, 4, 4), np.nan, np.float32))
    with pytest.raises(GamdDataError, match="NaN"):
        read_heat(bad, (4, 4))
    with pytest.raises(GamdDataError, match="shape"):
        read_heat(bad, (5, 4))
    bad.write_bytes(b"garbage")
    with pytest.raises(GamdDataError, match="cannot read"):
        read_heat(bad, (4, 4))
    (tmp_path / "gopro/train/group0/sharp/00000.png").unlink()
    with pytest.raises(GamdDataError, match="missing sharp"):
        find_triplets(gopro, "train")


def test_sampler_partitions_global_batch_and_resumes() -> None:
    full = StepBatchSampler(10, 2, steps=6, seed=5, world_size=1)
    r0 = StepBatchSampler(10, 1, steps=6, seed=5, rank=0, world_size=2)
    r1 = StepBatchSampler(10, 1, steps=6, seed=5, rank=1, world_size=2)
    for step in range(6):
        assert full.batch(step) == r0.batch(step) + r1.batch(step)
    later = StepBatchSampler(10, 2, steps=6, seed=5, start_step=3)
    assert list(later) == list(full)[3:]
    # each epoch visits every example once
    idx = [i for b in list(full)[:5] for i, _ in b]
    assert sorted(idx) == list(range(10))


def test_normalise_heat_rejects_bad_scale() -> None:
    from gamd.errors import GamdConfigError

    with pytest.raises(GamdConfigError):
        normalise_heat(torch.zeros(6, 2, 2), 0.0)
