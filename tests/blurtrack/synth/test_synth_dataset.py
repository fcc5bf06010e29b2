"""Dataset builder: layout, determinism, resume after a kill, shards and merge, CLI."""

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
from blurtrack.synth.triplet import TripletParams, make_triplet, triplet_rng

CAL = Calibration(Camera((128, 96), (110.0, 110.0, 63.5, 47.5), readout_s=0.01))


@pytest.fixture
def images(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    root = tmp_path / "imgs"
    for rel in ("train/a.png", "train/b.png", "test/c.png"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        img = cv2.GaussianBlur((rng.random((60, 90, 3)) * 255).astype(np.uint8), (5, 5), 1)
        cv2.imwrite(str(root / rel), img)
    return root


def spec(images: Path, count: int = 5, **kw) -> DatasetSpec:
    params = TripletParams(size=(64, 48), exposure_ms=(10, 20), **kw)
    return DatasetSpec(
        calib=calibration_to_dict(CAL),
        gyro="synthetic:0.8",
        images=str(images),
        count=count,
        seed=11,
        params=params,
        group=2,
    )


def digest(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.glob("*/*/*/*"))
        if not p.name.startswith(".")
    }


def test_layout_manifest_and_determinism(images: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    res = build(spec(images), out)
    assert res.made == 5 and res.skipped == 0
    recs = read_manifest(out / "manifest.jsonl")
    assert sorted(recs) == list(range(5))
    for r in recs.values():
        assert set(r) >= {"split", "name", "stem", "source_image", "gyro_segment", "seed", "params"}
        assert r["split"] == ("test" if r["source_image"].startswith("test/") else "train")
        heat = np.load(out / r["files"]["heat"], allow_pickle=False)
        assert heat.dtype == np.float32 and heat.shape == (6, 48, 64)
        blur = cv2.imread(str(out / r["files"]["blur"]), cv2.IMREAD_UNCHANGED)
        assert blur.shape == (48, 64, 3) and blur.dtype == np.uint8
        assert r["params"]["max_step_px"] <= 0.5
    assert (out / "dataset.yaml").read_text().startswith("format: blurtrack-dataset/1")
    out2 = tmp_path / "ds2"
    build(spec(images), out2, workers=2)  # other worker count, same bytes
    assert digest(out) == digest(out2)


def test_resume_after_kill_redoes_only_missing(images: Path, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    build(spec(images), out)
    before = digest(out)
    man = out / "manifest.jsonl"
    lines = man.read_bytes().splitlines(keepends=True)
    # A kill: the last record half written, one finished file missing, a temporary left over.
    man.write_bytes(b"".join(lines[:-1]) + lines[-1][:25])
    killed = json.loads(lines[-1])
    rec1 = json.loads(lines[1])
    (out / rec1["files"]["blur"]).unlink()
    tmp = (out / rec1["files"]["sharp"]).with_name(".000099.png.s0of1.1.tmp")
    tmp.write_bytes(b"partial")
    other = tmp.with_name(".000099.png.s1of2.1.tmp")  # another shard's, maybe still running
    other.write_bytes(b"partial")
    res = build(spec(images), out)
    assert res.made == 2 and res.skipped == 3
    assert digest(out) == before and not tmp.exists() and other.exists()
    other.unlink()
    recs = read_manifest(man)
    assert sorted(recs) == list(range(5)) and killed["index"] in recs
    with pytest.raises(SynthesisError, match="other parameters"):
        build(spec(images, count=6), out)
    with pytest.raises(SynthesisError, match="inside the image folder"):
        build(spec(images), images / "ds")
    with pytest.raises(SynthesisError, match="workers"):
        build(spec(images), out, workers=1000)
    with pytest.raises(SynthesisError, match="count"):
        spec(images, count=0)


def test_shards_on_separate_machines_merge(images: Path, tmp_path: Path) -> None:
    full = tmp_path / "full"
    build(spec(images), full)
    a, b = tmp_path / "a", tmp_path / "b"
    ra = build(spec(images), a, shard=(0, 2))
    rb = build(spec(images), b, shard=(1, 2))
    assert (ra.made, rb.made) == (3, 2)
    assert (a / "manifest-shard0.jsonl").is_file()
    summary = merge(a, [b])
    assert summary["triplets"] == 5 and summary["missing"] == 0
    assert digest(a) == digest(full)
    assert sorted(read_manifest(a / "manifest.jsonl")) == list(range(5))
    assert not (a / "manifest-shard0.jsonl").exists()
    assert build(spec(images), a).made == 0  # a merged dataset counts as done


def test_paper_mode_and_robust_heat_maps(images: Path) -> None:
    img = cv2.imread(str(images / "train/a.png"))
    from blurtrack.synth.motion import SyntheticSource
    from blurtrack.synth.perturb import Perturbation
    from blurtrack.synth.photometry import Photometry

    src = SyntheticSource(1.0)
    exact = make_triplet(img, CAL, src, TripletParams(size=(64, 48)), triplet_rng(1, 2))
    paper = make_triplet(
        img, CAL, src, TripletParams(size=(64, 48), mode="paper"), triplet_rng(1, 2)
    )
    assert paper.info["render_path"] == "paper" and exact.info["render_path"] == "remap"
    np.testing.assert_array_equal(exact.sharp, paper.sharp)
    noisy = Photometry(noise_shot=1e-3, noise_read=1e-3)
    clean = make_triplet(
        img, CAL, src, TripletParams(size=(64, 48), photometry=noisy), triplet_rng(1, 2)
    )
    robust = make_triplet(
        img,
        CAL,
        src,
        TripletParams(
            size=(64, 48),
            photometry=noisy,
            perturbation=Perturbation(timeshift_ms=3.0, focal_rel=0.02),
        ),
        triplet_rng(1, 2),
    )
    np.testing.assert_array_equal(robust.blur, clean.blur)  # blur (noise too) as without it
    assert np.abs(robust.heat - exact.heat).max() > 0.01
    assert robust.info["perturbation"]["timeshift_s"] != 0
    assert exact.info["bezier_fit"]["within_0.5px"] > 0.99

    with pytest.raises(SynthesisError, match="paper mode"):
        TripletParams(mode="paper", photometry=Photometry(noise_read=0.01))


def test_cli_synth_and_errors(images: Path, tmp_path: Path, capsys) -> None:
    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    out = tmp_path / "cli"
    args = [
        "synth",
        "--calib",
        str(cal),
        "--gyro",
        "synthetic",
        "--images",
        str(images),
        "--out",
        str(out),
        "--count",
        "2",
        "--size",
        "48x32",
        "--noise",
        "0.001,0.002",
        "--jpeg",
        "90",
        "--extras",
        "--png-compression",
        "6",
        "--saturation",
        "3",
    ]
    assert main(args) == 0
    rec = next(iter(read_manifest(out / "manifest.jsonl").values()))
    mask = cv2.imread(str(out / rec["files"]["mask"]), cv2.IMREAD_UNCHANGED)
    fit = np.load(out / rec["files"]["fit"], allow_pickle=False)
    assert mask.shape == (32, 48) and set(np.unique(mask)) <= {0, 255}
    assert fit.shape == (32, 48) and fit.max() < 0.5
    summary = json.loads((out / "summary.json").read_text())
    assert summary["made"] == 2 and summary["size"] == [48, 32]
    gs = tmp_path / "gs"
    assert main([*args[:8], str(gs), "--count", "1", "--size", "48x32", "--readout-ms", "0"]) == 0
    rec = next(iter(read_manifest(gs / "manifest.jsonl").values()))
    assert rec["params"]["readout_s"] == 0 and rec["params"]["render_path"] == "homography"
    assert main([*args[:-9], "--size", "48by32"]) == 2
    assert "--size must be WxH" in capsys.readouterr().err
    assert main(["synth-merge", str(tmp_path / "nothing")]) == 2
    bad = tmp_path / "bad"
    assert main([*args[:4], str(tmp_path / "missing.txt"), *args[5:7], "--out", str(bad)]) == 2
    assert "not found" in capsys.readouterr().err and not bad.exists()


def test_demo_dataset_from_shared_backgrounds(tmp_path: Path, shared_data: Path) -> None:
    from blurtrack.cli.demo import demo_dataset

    summary = demo_dataset(tmp_path / "demo", shared_data, count=2, size=(64, 36))
    assert summary["made"] == 2
    assert len(read_manifest(tmp_path / "demo" / "manifest.jsonl")) == 2


def test_sigkill_mid_build_then_resume(images: Path, tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "blurtrack",
        "synth",
        "--calib",
        str(cal),
        "--gyro",
        "synthetic:0.8",
        "--images",
        str(images),
        "--out",
        str(out),
        "--count",
        "40",
        "--size",
        "96x64",
        "--seed",
        "4",
    ]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[3])}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    man = out / "manifest.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if man.is_file() and man.read_bytes().count(b"\n") >= 3:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not list(out.glob("*/*/*/[!.]*.tmp"))  # nothing partial under a final name
    done_before = len(read_manifest(man))
    assert done_before >= 3
    assert subprocess.run([*cmd], env=env, capture_output=True).returncode == 0
    ref = tmp_path / "ref"
    assert (
        subprocess.run([*cmd[:-7], str(ref), *cmd[-6:]], env=env, capture_output=True).returncode
        == 0
    )
    assert sorted(read_manifest(man)) == list(range(40))
    assert digest(out) == digest(ref)


def test_min_blur_redraws_by_index_and_reports_the_count(images: Path, tmp_path: Path) -> None:
    base = tmp_path / "base"
    build(spec(images, count=8), base)
    lengths = {
        i: r["params"]["blur_length_px"]["median"]
        for i, r in read_manifest(base / "manifest.jsonl").items()
    }
    floor = float(np.median(list(lengths.values())))  # about half the first draws fall under
    out = tmp_path / "min"
    res = build(spec(images, count=8, min_blur_px=floor), out)
    recs = read_manifest(out / "manifest.jsonl")
    under = {i: r["draws_under_min_blur"] for i, r in recs.items()}
    assert all(r["params"]["blur_length_px"]["median"] >= floor for r in recs.values())
    # Draw 0 is the triplet of the dataset without a minimum: kept exactly when it reaches it.
    for i, n in under.items():
        assert (n == 0) == (lengths[i] >= floor)
        if n == 0:
            for kind, rel in recs[i]["files"].items():
                assert (out / rel).read_bytes() == (base / rel).read_bytes(), kind
    assert res.under_min_blur == sum(under.values()) > 0 and res.made == 8
    # A re-drawn index is draw k of its own generator (k draws before it fell under).
    i = next(i for i, n in under.items() if n)
    from blurtrack.synth.images import load_image
    from blurtrack.synth.motion import open_source

    params = spec(images, count=8, min_blur_px=floor).params
    src = open_source("synthetic:0.8")
    img = load_image(str(images), recs[i]["source_image"])
    meds = [
        np.median(np.hypot(*(t.heat[2:4] - t.heat[0:2])))
        for t in (
            make_triplet(img, CAL, src, params, triplet_rng(11, i, k)) for k in range(under[i] + 1)
        )
    ]
    assert all(m < floor for m in meds[:-1]) and meds[-1] >= floor
    out2 = tmp_path / "min2"  # other worker count, same bytes
    assert build(spec(images, count=8, min_blur_px=floor), out2, workers=2).under_min_blur == (
        res.under_min_blur
    )
    assert digest(out) == digest(out2)
    a, b = tmp_path / "a", tmp_path / "b"  # shards and merge: same triplets, same count
    build(spec(images, count=8, min_blur_px=floor), a, shard=(0, 2))
    build(spec(images, count=8, min_blur_px=floor), b, shard=(1, 2))
    summary = merge(a, [b])
    assert summary["draws_under_min_blur"] == res.under_min_blur and digest(a) == digest(out)
    again = build(spec(images, count=8, min_blur_px=floor), out)  # resumed: all done
    assert again.under_min_blur == 0 and again.under_min_blur_total == res.under_min_blur
    with pytest.raises(SynthesisError, match="other parameters"):
        build(spec(images, count=8, min_blur_px=floor / 2), out)
    with pytest.raises(SynthesisError, match="min_blur_px=1000 in 64 draws"):
        build(spec(images, count=1, min_blur_px=1000), tmp_path / "never")
    with pytest.raises(SynthesisError, match="min_blur_px must be"):
        TripletParams(min_blur_px=-1)
    # Off by default: the spec (hence dataset.yaml and the identity) has no such key.
    assert "min_blur_px" not in spec(images).params.to_dict()


def test_cli_min_blur_reports_draws_under_it(images: Path, tmp_path: Path, capsys) -> None:
    cal = tmp_path / "cal.yaml"
    write_calibration(CAL, cal)
    common = ["synth", "--calib", str(cal), "--gyro", "synthetic:0.8", "--images", str(images)]
    common += ["--count", "6", "--size", "64x48", "--exposure-ms", "10:20", "--seed", "11"]
    assert main([*common, "--out", str(tmp_path / "plain")]) == 0
    capsys.readouterr()
    lengths = [
        r["params"]["blur_length_px"]["median"]
        for r in read_manifest(tmp_path / "plain" / "manifest.jsonl").values()
    ]
    floor = float(np.max(lengths))  # every first draw but the longest falls under
    out = tmp_path / "min"
    assert main([*common, "--out", str(out), "--min-blur-px", f"{floor}"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    recs = read_manifest(out / "manifest.jsonl").values()
    n = sum(r["draws_under_min_blur"] for r in recs)
    assert summary["draws_under_min_blur"] == n >= 5 and summary["min_blur_px"] == floor
    assert f"{n} of {n + 6} draws had a median blur under --min-blur-px" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "bad"), "--min-blur-px", "nan"]) == 2
    assert "min_blur_px must be" in capsys.readouterr().err and not (tmp_path / "bad").exists()
