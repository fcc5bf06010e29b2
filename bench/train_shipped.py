"""Reproduce the shipped weights (``gamd/weights/*.pt``): data, training, export.

```
python bench/train_shipped.py data                 # blurtrack synth: BSDS500 train+val, real shake
python bench/train_shipped.py train --net gamd     # configs/gamd/shipped_gamd.yaml (resumable)
python bench/train_shipped.py train --net gamd_finetune  # from runs/gamd (shipped_gamd_finetune)
python bench/train_shipped.py train --net gamd_finetune2  # from runs/gamd_finetune
python bench/train_shipped.py train --net gamd_only
python bench/train_shipped.py export               # runs/*/checkpoints/last.pt -> gamd/weights/
```
The shipped ``gamd.pt`` is the second fine-tune (``runs/gamd_finetune2``): the 6000-step
``runs/gamd``, then 3000 steps from lr 3e-4 (``runs/gamd_finetune``), then 3000 from lr 1.5e-4;
``gamd_only.pt`` is ``runs/gamd_only``.
Data (``bench_out/shipped``, seeds fixed): 256 × 256 global-shutter pinhole cameras with
focal lengths 600 px and 2400 px (blur of about 0–8 and 0–40 px), exposures 10–30 ms, the real
GyroDeblurNet hand shake; 200 + 200 triplets from BSDS500 train and 100 + 100 from val form
the training split. The test splits (BSDS500 test, never trained on) are made by
``bench/bench_gamd.py --shipped``. Run from the repository root, with ``../shared/data``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from gamd.errors import GamdDataError

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench_out" / "shipped"
SHARED = REPO.parent / "shared" / "data"
#: (synth folder, BSDS500 folder, focal px, seed, count): the training split.
TRAIN_SETS = (
    ("train_f600", "train", 600.0, 0, 200),
    ("train_f2400", "train", 2400.0, 1, 200),
    ("val_f600", "val", 600.0, 0, 100),
    ("val_f2400", "val", 2400.0, 1, 100),
)
#: More triplets between the two cameras (blur of about 0-20 px: working scales 1-2.5, where
#: the 600 px camera gives none and the 2400 px one few), from the same BSDS500 train and val
#: photos with new shake segments and crops; with TRAIN_SETS they form the split
#: ``train_ft3`` of the third fine-tune stage.
EXTRA_SETS = (
    ("train_f1200", "train", 1200.0, 4, 200),
    ("val_f1200", "val", 1200.0, 4, 100),
)
SIZE = (256, 256)
#: Shipped weights file -> the training run (``OUT/runs/<run>``) whose last checkpoint it is.
EXPORT_RUNS = {"gamd": "gamd_finetune2", "gamd_only": "gamd_only"}
#: Self-ensemble size written into both shipped files' ``data.ensemble`` at export (inference
#: only: ``gamd eval`` and ``gamd deblur`` average over the 4 flips unless ``--ensemble``).
EXPORT_ENSEMBLE = 4
#: Runs ``train --net`` knows, each from ``configs/gamd/shipped_<run>.yaml``.
RUNS = ("gamd", "gamd_finetune", "gamd_finetune2", "gamd_finetune3", "gamd_only")


def write_calibration(path: Path, size: tuple[int, int], focal_px: float) -> Path:
    """A global-shutter pinhole camera of ``size`` (W, H) and focal length ``focal_px``."""
    from blurtrack.geometry.calibration import Calibration
    from blurtrack.geometry.camera import Camera
    from blurtrack.io.calibration import write_calibration

    w, h = size
    cam = Camera(resolution=(w, h), intrinsics=(focal_px, focal_px, (w - 1) / 2, (h - 1) / 2))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_calibration(Calibration(camera=cam), path)
    return path


def synth(
    images: Path,
    out: Path,
    size: tuple[int, int],
    focal_px: float,
    seed: int,
    count: int,
    shared: Path = SHARED,
    extra: list[str] | None = None,
) -> Path:
    """One ``blurtrack synth`` call with the real shake (resumes a finished folder)."""
    calib = write_calibration(
        out.parent / f"calib_{size[0]}x{size[1]}_f{focal_px:g}.yaml", size, focal_px
    )
    gyro = shared / "real" / "gyrodeblurnet-shake" / "gyro_train.txt"
    cmd = [sys.executable, "-m", "blurtrack", "synth", "--calib", str(calib), "--gyro"]
    cmd += [str(gyro), "--images", str(images), "--out", str(out), "--seed", str(seed)]
    cmd += ["--size", f"{size[0]}x{size[1]}", "--count", str(count), *(extra or [])]
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise GamdDataError(f"synth failed: {proc.stderr.strip().splitlines()[-1:]}")
    return out


def link_split(src: Path, dst_split: Path, tag: str) -> int:
    """Symlink each ``src/<split>/<name>`` group into ``dst_split/<tag>_<split>_<name>``."""
    n = 0
    for blur in sorted(src.glob("*/*/blur")):
        g = blur.parent
        dst = dst_split / f"{tag}_{g.parent.name}_{g.name}"
        dst.mkdir(parents=True, exist_ok=True)
        for sub in ("blur", "sharp", "heat"):
            if (g / sub).is_dir() and not (dst / sub).exists():
                (dst / sub).symlink_to((g / sub).resolve(), target_is_directory=True)
        n += 1
    return n


def build_data(out: Path = OUT, shared: Path = SHARED) -> Path:
    """The training splits of the shipped weights: ``out/data/train`` (TRAIN_SETS) and
    ``out/data/train_ft3`` (TRAIN_SETS + EXTRA_SETS)."""
    bg = shared / "backgrounds" / "bsds500"
    if not bg.is_dir():
        raise GamdDataError(f"BSDS500 not found at {bg}")
    for name, folder, focal, seed, count in TRAIN_SETS + EXTRA_SETS:
        synth(bg / folder, out / "synth" / name, SIZE, focal, seed, count, shared)
        if (name, folder, focal, seed, count) in TRAIN_SETS:
            link_split(out / "synth" / name, out / "data" / "train", name)
        link_split(out / "synth" / name, out / "data" / "train_ft3", name)
    return out / "data"


def export(out: Path = OUT, dest: Path | None = None) -> list[Path]:
    """Copy each run's last checkpoint, weights only, to ``gamd/weights/<net>.pt``, with the
    self-ensemble of :data:`EXPORT_ENSEMBLE`."""
    from gamd.checkpoint import export_weights
    from gamd.weights import SHIPPED, WEIGHTS_DIR

    written = []
    for net in SHIPPED:
        src = out / "runs" / EXPORT_RUNS[net] / "checkpoints" / "last.pt"
        dst = (dest or WEIGHTS_DIR) / f"{net}.pt"
        written.append(export_weights(src, dst, {"ensemble": EXPORT_ENSEMBLE}))
    return written


def main(argv: list[str] | None = None) -> int:
    doc = (__doc__ or "").split("\n")[0]
    p = argparse.ArgumentParser(prog="python bench/train_shipped.py", description=doc)
    sub = p.add_subparsers(dest="what", required=True)
    sub.add_parser("data")
    t = sub.add_parser("train")
    t.add_argument("--net", choices=RUNS, required=True)
    sub.add_parser("export")
    args = p.parse_args(argv)
    if args.what == "data":
        print(f"training split in {build_data()}")
    elif args.what == "train":
        from gamd.cli import main as gamd_main

        config = REPO / "configs" / "gamd" / f"shipped_{args.net}.yaml"
        return gamd_main(["train", "--config", str(config), "--resume", "auto"])
    else:
        for path in export():
            print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
