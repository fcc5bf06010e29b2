"""Dataset lock, input identity and hostile merges: two runs never make the same triplets,
shards of other inputs never merge, manifest entries stay confined, incomplete merges fail
without changing anything."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.errors import SynthesisError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import calibration_to_dict, write_calibration
from blurtrack.synth.dataset import DatasetSpec, build, read_manifest
from blurtrack.synth.merge import merge
from blurtrack.synth.store import dataset_lock
from blurtrack.synth.triplet import TripletParams

CAL = Calibration(Camera((128, 96), (110.0, 110.0, 63.5, 47.5), readout_s=0.01))


def make_images(root: Path, shape: tuple[int, int] = (60, 90), seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    for rel in ("train/a.png", "train/b.png", "test/c.png"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / rel), (rng.random((*shape, 3)) * 255).astype(np.uint8))
    return root


def spec(images: Path, count: int = 4) -> DatasetSpec:
    return DatasetSpec(
        calib=calibration_to_dict(CAL),
        gyro="synthetic:0.8",
        images=str(images),
        count=count,
        seed=3,
        params=TripletParams(size=(32, 24), exposure_ms=(10, 20)),
        group=2,
    )


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones too, lock files aside) and its hash."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and not p.name.endswith(".lock")
    }


def test_two_runs_on_one_dataset_do_not_both_make_it(tmp_path: Path, capsys) -> None:
    images = make_images(tmp_path / "imgs")
    out = tmp_path / "ds"
    tried: list[str] = []

    def second_run(done: int, total: int) -> None:
        if done == 1 and not tried:  # while the first run holds the dataset
            for shard in ((0, 1), (0, 2), (1, 2)):
                with pytest.raises(SynthesisError, match="being written by another run"):
                    build(spec(images), out, shard)
                tried.append(f"{shard}")

    assert build(spec(images), out, progress=second_run).made == 4
    assert len(tried) == 3
    lines = (out / "manifest.jsonl").read_text().splitlines()
    assert len(lines) == 4 and sorted(read_manifest(out / "manifest.jsonl")) == [0, 1, 2, 3]

    # Shards share the folder, but a shard never runs twice and a whole build waits.
    sh = tmp_path / "sh"

    def during_shard0(done: int, total: int) -> None:
        if done == 1 and len(tried) == 3:
            tried.append("shard1")
            assert build(spec(images), sh, (1, 2)).made == 2  # the other shard: allowed
            for shard in ((0, 2), (0, 1)):
                with pytest.raises(SynthesisError, match="being written by another run"):
                    build(spec(images), sh, shard)

    assert build(spec(images), sh, (0, 2), progress=during_shard0).made == 2
    assert tried[-1] == "shard1"
    assert merge(sh)["triplets"] == 4

    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    with dataset_lock(out):
        argv = ["synth", "--calib", str(cal), "--gyro", "synthetic", "--images", str(images)]
        assert main([*argv, "--out", str(out), "--count", "4"]) == 2
        assert main(["synth-merge", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all("is being written by another run" in e for e in err)


def test_resume_refuses_changed_photos(tmp_path: Path, capsys) -> None:
    images = make_images(tmp_path / "imgs")
    out = tmp_path / "ds"
    build(spec(images), out)
    cv2.imwrite(str(images / "train" / "d.png"), np.zeros((60, 90, 3), np.uint8))
    with pytest.raises(SynthesisError, match="made from other inputs"):
        build(spec(images), out)


def test_merge_refuses_shards_of_other_photo_folders(tmp_path: Path) -> None:
    a_imgs = make_images(tmp_path / "m1" / "photos")
    b_imgs = make_images(tmp_path / "m2" / "photos", shape=(64, 96), seed=5)  # same names
    a, b = tmp_path / "a", tmp_path / "b"
    build(spec(a_imgs), a, (0, 2))
    build(spec(b_imgs), b, (1, 2))
    before = (tree(a), tree(b))
    with pytest.raises(SynthesisError, match="identities differ"):
        merge(a, [b])
    assert (tree(a), tree(b)) == before  # nothing moved
    assert main(["synth-merge", str(a), str(b)]) == 2


def test_merge_confines_entries_and_refuses_missing_shards(tmp_path: Path, capsys) -> None:
    images = make_images(tmp_path / "imgs")
    a, b = tmp_path / "a", tmp_path / "b"
    build(spec(images), a, (0, 2))
    build(spec(images), b, (1, 2))
    # A hostile record in b: its heat map "is" b's dataset.yaml, to be moved over a's.
    man = b / "manifest-shard1.jsonl"
    recs = [json.loads(line) for line in man.read_text().splitlines()]
    recs[0]["files"]["heat"] = "dataset.yaml"
    recs[1]["files"]["blur"] = "../a/dataset.yaml"
    man.write_text("".join(json.dumps(r) + "\n" for r in recs))
    before = (tree(a), tree(b))

    assert main(["synth-merge", str(a), str(tmp_path / "no-such-shard")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "shard folder not found" in err[0]
    assert main(["synth-merge", str(a), str(b)]) == 2  # both of b's records refused: missing
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "2 of 4 triplets are missing (indices 1, 3)" in err[0]
    assert main(["synth-merge", str(a)]) == 2  # shard 1 never built into a
    assert (tree(a), tree(b)) == before  # refused merges change nothing

    assert main(["synth-merge", str(a), str(b), "--allow-missing"]) == 0
    assert "2 missing" in capsys.readouterr().out
    assert tree(a)["dataset.yaml"] == before[0]["dataset.yaml"]
    assert (b / "dataset.yaml").is_file()
    assert sorted(read_manifest(a / "manifest.jsonl")) == [0, 2]
    summary = json.loads((a / "summary.json").read_text())
    assert summary["missing"] == 2 and summary["lost_records"] == 2
