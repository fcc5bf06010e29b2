"""Detection on natural photographs that hold no point-light streak (prints JSON).

The BSDS500 photographs in ``../shared/data/backgrounds/bsds500`` are daylight scenes (sky,
water, walls, foliage, faces): every streak the detector finds there is on an extended source,
so every ``quality_ok`` detection is a false one. Measured per photo (each as stored, and
dimmed to a quarter with the same shot noise a dark frame has, which lifts fewer regions over
the threshold and leaves small bright ones: highlights, lamps, reflections; and with
``--shake``, shaken as a hand-held night photograph is: the linear light blurred by the kernel
of a real hand shake, :func:`shake_kernel`, then exposed three ways, :data:`SHAKE_EXPOSURES`,
with the same noise): streaks found, ``quality_ok``, and
the ``source`` split; pooled: photos with any ``quality_ok``, the total and the share of
streaks called ``point``. Shaken, every extended source (a window, a sign, a white wall) draws
the very streak a point light would beside it, only wider or larger: the condition of the
night photographs that issue 45 is judged on.

Usage: ``python bench/natural_negatives.py --split test --count 100 [--shake]``; any folder of
photographs (``*.jpg``, ``*.png``) with ``--images DIR`` (night photographs of lit signs and
windows: every ``quality_ok`` there is to be looked at, for some of their lights are points).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blurtrack.detect import detect_frame  # noqa: E402
from blurtrack.detect.session.orientation import combine  # noqa: E402
from blurtrack.detect.session.table import build_table, frame_rows  # noqa: E402
from blurtrack.features.blur_estimate import rasterize  # noqa: E402
from blurtrack.geometry.gyro import GyroTrace  # noqa: E402
from blurtrack.io.shake import read_shake_trace  # noqa: E402
from blurtrack.synth.photometry import decode_srgb8, encode_srgb8  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "backgrounds" / "bsds500"
SHAKE = ROOT.parent / "shared" / "data" / "real" / "gyrodeblurnet-shake" / "gyro_train.txt"
#: The shaken photographs: a pinhole of this focal length (px; a 50 degree view across the
#: 481 px side, scaled with a larger photograph's longer side), an exposure of this long (s; a
#: night photograph's 1/15 s at hand-held rates of ~0.7 rad/s: kernels 10-35 px across, median
#: 20, on the 481 px photographs), and the exposures ``(power, gain)`` of
#: the linear light ``gain * light ** power``: a quarter, twice (the brightest regions blow
#: out), and a night scene (the cube leaves the bright regions lit on a dark ground, as lit
#: windows and signs are, and four times their light blows them out).
SHAKE_FOCAL_PX = 520.0
SHAKE_EXPOSURE_S = 1.0 / 15.0
SHAKE_EXPOSURES = ((1.0, 0.25), (1.0, 2.0), (3.0, 4.0))


def dark_noise(x: np.ndarray, seed: int) -> np.ndarray:
    """``x`` (8-bit code values, float) with the shot and read noise of a dark 8-bit frame."""
    rng = np.random.default_rng(seed)
    return np.asarray(x + rng.normal(0.0, 1.0, x.shape) * np.sqrt(0.5 * np.clip(x, 0, None) + 1.0))


def dimmed(img: np.ndarray, seed: int) -> np.ndarray:
    """``img`` at a quarter of its light, with :func:`dark_noise`."""
    x = dark_noise(img.astype(np.float64) * 0.25, seed)
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def shake_kernel(trace: GyroTrace, t0_s: float, exposure_s: float, focal_px: float) -> np.ndarray:
    """The blur kernel (2-D, sum 1) of a rotation-only shake at the image centre: the path of a
    point at infinity over ``[t0_s, t0_s + exposure_s]`` of the real ``trace`` (rad/s, camera
    axes x right, y down, z forward; small angles, the roll about the centre moves it not),
    ``focal_px`` away, sampled at 0.5 ms steps and splatted bilinearly
    (:func:`blurtrack.features.blur_estimate.rasterize`)."""
    t = np.arange(t0_s, t0_s + exposure_s, 5e-4)
    w = trace.omega_at(t)
    ang = np.cumsum(w, axis=0) * 5e-4
    # A rotation about +y moves a point at infinity along -x in the image, about +x along +y.
    path = np.column_stack([-focal_px * ang[:, 1], focal_px * ang[:, 0]])
    extent = float(np.max(path.max(axis=0) - path.min(axis=0)))
    return rasterize(path, 2 * (int(np.ceil(extent)) // 2) + 5)


def shaken(img: np.ndarray, kernel: np.ndarray, power: float, gain: float, seed: int) -> np.ndarray:
    """``img`` (8-bit sRGB) in linear light raised to ``power``, blurred by ``kernel``, exposed
    at ``gain`` (clipped at full scale), with :func:`dark_noise`, 8-bit sRGB again."""
    lin = decode_srgb8(img).astype(np.float32) ** np.float32(power)
    blurred = cv2.filter2D(lin, -1, kernel.astype(np.float32), borderType=cv2.BORDER_REFLECT)
    x = dark_noise(blurred.astype(np.float64) * gain * 255.0, seed)
    return encode_srgb8(np.clip(x / 255.0, 0.0, 1.0))


def frame_table(img: np.ndarray):  # type: ignore[no-untyped-def]
    """The streak table of one image, image evidence only (no gyro)."""
    fs = detect_frame(img)
    return build_table([frame_rows(0, 0, fs, combine(np.zeros((len(fs), 3))))])


def measure(img: np.ndarray) -> dict[str, Any]:
    table = frame_table(img)
    return {
        "streaks": len(table),
        "quality_ok": int(table.quality_ok.sum()) if len(table) else 0,
        "source": {k: int(v) for k, v in table.source.value_counts().items()} if len(table) else {},
    }


def pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    streaks = sum(r["streaks"] for r in rows)
    point = sum(r["source"].get("point", 0) for r in rows)
    return {
        "photos": len(rows),
        "photos_with_quality_ok": sum(1 for r in rows if r["quality_ok"]),
        "quality_ok": sum(r["quality_ok"] for r in rows),
        "streaks": streaks,
        "point_share": point / max(streaks, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--images", type=Path, default=None, help="a folder of photographs instead")
    ap.add_argument("--shake", action="store_true", help="also the shaken night exposures")
    ap.add_argument("--shakes", type=int, default=1, help="shakes per photograph (--shake)")
    ap.add_argument("--hits", type=Path, default=None, help="write the frames with quality_ok here")
    args = ap.parse_args()
    folder = args.images if args.images is not None else DATA / args.split
    files = sorted(f for f in folder.glob("*") if f.suffix.lower() in (".jpg", ".jpeg", ".png"))
    files = files[: args.count]
    if not files:
        print(f"no photographs under {folder}", file=sys.stderr)
        return 2
    trace = read_shake_trace(SHAKE) if args.shake else None
    shakes = [(f"shaken_p{p:g}_x{g:g}", p, g) for p, g in SHAKE_EXPOSURES] if args.shake else []
    names = ["as_stored", "dimmed"] + [n for n, _, _ in shakes]
    out: dict[str, list[dict[str, Any]]] = {name: [] for name in names}
    rng = np.random.default_rng(0)
    for k, f in enumerate(files * max(args.shakes, 1) if args.shake else files):
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            print(f"cannot decode {f.name}", file=sys.stderr)
            return 2
        first = k < len(files)  # as stored and dimmed once; each round of shakes its own kernel
        variants = [("as_stored", img), ("dimmed", dimmed(img, k))] if first else []
        if trace is not None:
            while True:  # a window of the trace without a dropout
                t0 = float(rng.uniform(trace.t_s[0], trace.t_s[-1] - SHAKE_EXPOSURE_S))
                if trace.covers(t0, t0 + SHAKE_EXPOSURE_S):
                    break
            focal = SHAKE_FOCAL_PX * max(max(img.shape[:2]) / 481.0, 1.0)
            kern = shake_kernel(trace, t0, SHAKE_EXPOSURE_S, focal)
            variants += [(n, shaken(img, kern, p, g, k)) for n, p, g in shakes]
        for name, im in variants:
            row = {"image": f.name, **measure(im)}
            out[name].append(row)
            if row["quality_ok"]:
                print(f"{name} {f.name}: {row}", file=sys.stderr)
                if args.hits is not None:
                    args.hits.mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(args.hits / f"{name}-{f.stem}-{k}.png"), im)
    result = {name: {"pooled": pooled(rows), "photos": rows} for name, rows in out.items()}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
