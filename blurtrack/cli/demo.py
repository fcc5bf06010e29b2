"""``blurtrack demo --out DIR``: the whole pipeline on the embedded simulated rig (``make demo``).

simulate → detect → calibrate (printed beside the simulator's truth) → report → import the
real recordings → synthesise a small dataset with the fitted calibration → deblur its test
image with the shipped GAMD weights → before/after picture (this is the one demo module:
:func:`demo_dataset` is its synthesis step, :func:`demo_deblur` its deblurring step, and
:func:`demo_train` the optional short training run of ``--train-steps N``). Each step runs
the command a user would type; the first failing step stops the demo with its one-line
reason and a non-zero exit.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from blurtrack.io.atomic import write_json_atomic

if TYPE_CHECKING:
    pass

REPO = Path(__file__).resolve().parents[2]
DEFAULT_DATA = REPO.parent / "shared" / "data"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on the simulated rig")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    p.add_argument(
        "--data",
        type=Path,
        default=DEFAULT_DATA,
        help="the shared real data (default: %(default)s, ../shared/data beside the repository)",
    )
    p.add_argument("--frames", type=int, default=40, help="simulated frames")
    p.add_argument("--seed", type=int, default=1, help="simulator seed")
    p.add_argument(
        "--train-steps",
        type=int,
        default=0,
        help="0 (default): deblur with the shipped GAMD weights; N > 0: train tiny GAMD from "
        "scratch for N steps instead (a pipeline check, not a trained network)",
    )
    p.set_defaults(func=run)


def _step(title: str, fn: Callable[[], int]) -> None:
    from blurtrack.errors import BlurTrackError

    print(f"\n== {title}", flush=True)
    t0 = time.perf_counter()
    rc = fn()
    if rc != 0:
        raise BlurTrackError(f"demo step '{title}' failed with exit status {rc}")
    print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)


def run(args: argparse.Namespace) -> int:
    from blurtrack.cli import main as bt
    from blurtrack.errors import BlurTrackError
    from blurtrack.io.guard import check_new_folder

    out: Path = args.out
    data: Path = args.data
    if not data.is_dir():
        raise BlurTrackError(f"shared data not found at {data} (use --data)")
    check_new_folder(out, "--out")  # the one guard: not in a recording, new or empty
    out.mkdir(parents=True, exist_ok=True)
    sim = out / "sim"
    t_start = time.perf_counter()

    _step(
        "simulate a laser-grid session (realistic preset)",
        lambda: bt(
            [
                "simulate",
                str(sim),
                "--preset",
                "realistic",
                "--frames",
                str(args.frames),
                "--seed",
                str(args.seed),
            ]
        ),
    )
    _step(
        "detect the streaks",
        lambda: bt(
            [
                "detect",
                str(sim),
                "--overlay",
                str(out / "detect.png"),
            ]
        ),
    )
    _step(
        "calibrate with CasADi",
        lambda: bt(["calibrate", str(sim), "--out", str(out / "calib.yaml")]),
    )
    _step(
        "endpoint-error report",
        lambda: bt(
            ["report", str(sim), "--calib", str(out / "calib.yaml"), "--out", str(out / "report")]
        ),
    )
    real = data / "real"
    _step(
        "import the DeepGyro recording (predicted trajectories drawn)",
        lambda: bt(
            [
                "import",
                "deepgyro",
                str(real / "deepgyro-shield"),
                str(out / "deepgyro"),
                "--overlays",
                "7",
            ]
        ),
    )
    _step(
        "import the MARS logger recording (predicted trajectories drawn)",
        lambda: bt(
            [
                "import",
                "marslogger",
                str(real / "marslogger-phone"),
                str(out / "marslogger"),
                "--overlays",
                "10",
            ]
        ),
    )
    _step("synthesise calibrated training triplets", lambda: _synth(out, data))
    if args.train_steps < 0:
        raise BlurTrackError(f"--train-steps must be >= 0, got {args.train_steps}")
    _step(
        "deblur a test image with the shipped GAMD weights"
        if args.train_steps == 0
        else "train GAMD briefly and deblur a test image",
        lambda: _gamd(out, args.train_steps, sys.stderr.isatty()),
    )
    print(f"\ndemo finished in {time.perf_counter() - t_start:.0f} s; outputs:")
    for name, what in [
        ("sim/", "simulated session with truth.yaml"),
        ("detect.png", "detected streaks over a frame"),
        ("calib.yaml", "fitted calibration (Kalibr keys)"),
        ("report/report.html", "endpoint-error report"),
        ("deepgyro/overlays/", "predicted trajectories on the DeepGyro frames"),
        ("marslogger/overlays/", "predicted trajectories on the MARS logger frames"),
        ("dataset/", "training triplets (sharp, blur, heat maps)"),
        (
            "gamd/before_after.png",
            "blurred | GAMD output | sharp, with PSNR/SSIM (and in summary.json)",
        ),
    ]:
        print(f"   {out / name}: {what}")
    return 0


def _synth(out: Path, data: Path) -> int:
    from blurtrack.io.calibration import read_calibration

    calib = read_calibration(out / "calib.yaml")
    res = demo_dataset(out / "dataset", data, count=24, size=(256, 192), calib=calib)
    print(f"   {json.dumps({k: v for k, v in res.items() if not isinstance(v, (dict, list))})}")
    return 0


def _gamd(out: Path, steps: int, progress: bool) -> int:
    if steps == 0:
        res = demo_deblur(out / "dataset", out / "gamd")
        what = f"shipped weights {Path(res['checkpoint']).name}"
    else:
        res = demo_train(out / "dataset", out / "gamd", steps=steps, progress=progress)
        what = f"{steps} training steps from scratch (a short CPU run, not a trained network)"
    gain = res["restored_psnr_db"] - res["blurred_psnr_db"]
    print(
        f"   {what}; test image {res['image']}: blurred "
        f"{res['blurred_psnr_db']:.2f} dB / SSIM {res['blurred_ssim']:.4f}, restored "
        f"{res['restored_psnr_db']:.2f} dB / SSIM {res['restored_ssim']:.4f} ({gain:+.2f} dB)"
    )
    return 0


def demo_calibration() -> Any:
    """A 720p phone-class camera: 65° horizontal field of view, 20 ms rolling-shutter readout."""
    from blurtrack.geometry.calibration import Calibration
    from blurtrack.geometry.camera import Camera

    return Calibration(Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5), readout_s=0.02))


def demo_dataset(
    out: str | Path,
    data: str | Path,
    count: int = 8,
    size: tuple[int, int] = (320, 180),
    calib: Any = None,
    workers: int = 1,
) -> dict[str, Any]:
    """Build (or resume) a small dataset at ``out`` from ``data/backgrounds/bsds500``.

    BSDS500 photographs blurred with the real GyroDeblurNet shake (synthetic shake when that file
    is absent) through a phone-like calibration (or ``calib``), exact mode, mild noise; returns
    the build summary.
    """
    from blurtrack.errors import SynthesisError
    from blurtrack.io.calibration import calibration_to_dict
    from blurtrack.synth.dataset import DatasetSpec, build
    from blurtrack.synth.photometry import Photometry
    from blurtrack.synth.triplet import TripletParams

    data = Path(data)
    images = data / "backgrounds" / "bsds500"
    if not images.is_dir():
        raise SynthesisError(f"demo backgrounds not found at {images}")
    shake = data / "real" / "gyrodeblurnet-shake"
    gyro = str(shake.resolve()) if shake.is_dir() else "synthetic:0.7"
    params = TripletParams(
        size=size, exposure_ms=(10.0, 30.0), photometry=Photometry(noise_shot=2e-4, noise_read=2e-3)
    )
    spec = DatasetSpec(
        calib=calibration_to_dict(calib or demo_calibration()),
        gyro=gyro,
        images=str(images.resolve()),
        count=count,
        seed=0,
        params=params,
        group=max(1, count // 2),
    )
    res = build(spec, out, workers=workers)
    return {"out": str(out), "gyro": Path(gyro).name, **res.to_dict()}


def _before_after(
    dataset: str | Path, out: Path, restore_fn: Any, heat_scale_px: float
) -> dict[str, Any]:
    """Restore the first test image (train split for tiny sets) with ``restore_fn(blur, heat)``
    and write ``out/before_after.png`` (:func:`before_after_figure`); PSNR/SSIM of the blurred
    and the restored image."""
    from blurtrack.detect.overlay import figure_pixels
    from blurtrack.io.images import write_image
    from gamd.data import DeblurDataset
    from gamd.evaluate import psnr_ssim

    split = "test" if (Path(dataset) / "test").is_dir() else "train"  # tiny demo sets
    test = DeblurDataset(dataset, split, crop=None, augment=False, heat_scale_px=heat_scale_px)
    item = test.full(0)
    restored = restore_fn(item["blur"], item["heat"]).permute(1, 2, 0).numpy()
    blur = item["blur"].permute(1, 2, 0).numpy()
    sharp = item["sharp"].permute(1, 2, 0).numpy()
    picture = out / "before_after.png"
    (bp, bs), (rp, rs) = psnr_ssim(blur, sharp), psnr_ssim(restored, sharp)
    name = f"{split}/{test.triplets[0].name}"
    fig = before_after_figure(blur, restored, sharp, (bp, bs), (rp, rs), name)
    write_image(picture, figure_pixels(fig))
    return {
        "image": name,
        "picture": str(picture),
        "blurred_psnr_db": bp,
        "blurred_ssim": bs,
        "restored_psnr_db": rp,
        "restored_ssim": rs,
    }


def before_after_figure(
    blur: Any,
    restored: Any,
    sharp: Any,
    blurred_psnr_ssim: tuple[float, float],
    restored_psnr_ssim: tuple[float, float],
    image: str = "",
) -> Any:
    """Three labelled panels, "blurred input", "GAMD output", "sharp reference" (float RGB
    ``(H, W, 3)`` in [0, 1]), each at a whole number of picture pixels per image pixel (at
    least 480 px wide, images wider than 600 px scaled down), with the PSNR/SSIM of the blurred
    and the restored image against the sharp one written under their panels. Returns the
    :class:`matplotlib.figure.Figure` (no pyplot state)."""
    import math

    import numpy as np
    from matplotlib.figure import Figure

    h, w = np.asarray(blur).shape[:2]
    scale = float(math.ceil(480 / w)) if w < 480 else min(1.0, 600 / w)
    pw, ph = w * scale, h * scale
    pad, top, bottom, dpi = 14.0, 72.0, 52.0, 100.0
    fig_w, fig_h = 3 * pw + 4 * pad, ph + top + bottom
    fig = Figure(figsize=(fig_w / dpi, fig_h / dpi), dpi=dpi)
    (bp, bs), (rp, rs) = blurred_psnr_ssim, restored_psnr_ssim
    notes = [
        f"PSNR {bp:.2f} dB\nSSIM {bs:.3f}",
        f"PSNR {rp:.2f} dB ({rp - bp:+.2f} dB)\nSSIM {rs:.3f} ({rs - bs:+.3f})",
        "PSNR / SSIM measured\nagainst this image",
    ]
    for k, (img, label, note) in enumerate(
        zip(
            (blur, restored, sharp),
            ("blurred input", "GAMD output", "sharp reference"),
            notes,
            strict=True,
        )
    ):
        ax = fig.add_axes(((pad + k * (pw + pad)) / fig_w, bottom / fig_h, pw / fig_w, ph / fig_h))
        ax.imshow(np.clip(np.asarray(img), 0.0, 1.0), interpolation="nearest")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"({'abc'[k]}) {label}", fontsize=12, pad=4)
        ax.text(
            0.5, -0.02, note, transform=ax.transAxes, ha="center", va="top", fontsize=10.5,
            linespacing=1.3,
        )  # fmt: skip
    what = f" on {image}" if image else ""
    fig.suptitle(f"GAMD deblurring{what}", y=1.0 - 6.0 / fig_h, va="top", fontsize=13)
    return fig


def demo_deblur(
    dataset: str | Path, out_dir: str | Path, checkpoint: str | Path | None = None
) -> dict[str, Any]:
    """Deblur the first test image with the shipped GAMD weights (or ``checkpoint``), the way
    ``gamd eval`` and ``gamd deblur`` restore (gate, working resolution, rolling-shutter
    recentring from the weights' config); write the before/after picture and the summary."""
    from gamd.checkpoint import load_model
    from gamd.evaluate import restore
    from gamd.weights import shipped_weights

    out = Path(out_dir)
    ckpt = Path(checkpoint) if checkpoint is not None else shipped_weights("gamd")
    model, config, step = load_model(ckpt)
    options = config.data.restore_options()
    summary = _before_after(
        dataset,
        out,
        lambda blur, heat: restore(model, blur, heat, options),
        config.data.heat_scale_px,
    )
    summary = {**summary, "steps": 0, "checkpoint": str(ckpt), "weights_step": step}
    write_json_atomic(out / "summary.json", summary)
    return summary


def demo_train(
    dataset: str | Path,
    out_dir: str | Path,
    steps: int = 100,
    crop: int = 64,
    batch_size: int = 4,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = True,
) -> dict:
    """Train tiny GAMD for ``steps`` steps and write the before/after picture; returns the
    summary (PSNR/SSIM of the blurred and the restored test image)."""
    from gamd.config import RunConfig
    from gamd.evaluate import restore
    from gamd.train import train

    out = Path(out_dir)
    config = RunConfig.from_dict(
        {
            "model": {"name": "gamd", "preset": "tiny"},
            "data": {"root": str(dataset), "crop": crop},
            "train": {
                "out_dir": str(out / "run"),
                "steps": steps,
                "batch_size": batch_size,
                "lr": 1e-3,
                "milestones": [max(1, 3 * steps // 4)],
                "seed": seed,
                "threads": threads,
                "checkpoint_every": steps,
                "progress": progress,
                "tensorboard": False,
            },
        }
    )
    res = train(config, resume="auto")
    assert res.model is not None  # train() returns the trained model
    model = res.model
    summary = _before_after(
        dataset,
        out,
        lambda blur, heat: restore(model, blur, heat),
        config.data.heat_scale_px,
    )
    summary = {**summary, "steps": steps, "checkpoint": str(res.checkpoint)}
    write_json_atomic(out / "summary.json", summary)
    return summary
