"""Validation of blurtrack.features.blur_estimate on synthetic blur of real photographs
(BSDS500 test split): known kernels, the estimator's straight-line blur vector against the
truth, and kernel scores of the true kernel against wrong ones (negative controls).

Each sample: a BSDS500 test photograph, decoded to linear light (sRGB), a random kernel
(straight, or a quadratic Bézier arc with the control point off the chord by up to
``--bow`` of the length: the heat maps' trajectory form, blurtrack.geometry.heatmap), blurred
in linear light, shot/read noise, 8-bit sRGB and a JPEG round trip (blurtrack.synth.photometry),
decoded again; one square tile is measured. Defaults match bench/deepgyro_blur.py's working
tiles (128 px, cepstrum radius 60, blur 10-55 px).

Reported: endpoint error of the estimated blur vector vs the true chord ``q(1) - q(0)``
(sign-free; median, p90, share under 2 px and under 10 % of the length), and the share of
samples where the true kernel scores above each control: rotated 90°, only the first half of
the exposure, and 1.3x too long. (A time-reversed kernel is the same image: not a control.)

    PYTHONPATH=$PWD .venv/bin/python bench/blur_estimate_synth.py [--n 40] [--out r.json]

Prints JSON. About 2 minutes on 2 busy CPU cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from json_out import emit

from blurtrack.features import blur_estimate as be
from blurtrack.synth.images import list_images, load_image, split_of
from blurtrack.synth.photometry import decode_srgb8, encode_srgb8, jpeg_roundtrip

REPO = Path(__file__).resolve().parents[1]
DEFAULT_IMAGES = REPO.parent / "shared" / "data" / "backgrounds" / "bsds500"


def bezier(q0: np.ndarray, ctrl: np.ndarray, q1: np.ndarray, n: int = 32) -> np.ndarray:
    """Quadratic Bézier ``(n, 2)``: the heat maps' trajectory form."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) ** 2 * q0 + 2 * t * (1 - t) * ctrl + t**2 * q1


def sample(
    gray_lin: np.ndarray, traj: np.ndarray, tile: int, radius: int, rng, jpeg: int = 90
) -> np.ndarray:
    """A blurred, noisy, 8-bit JPEG tile (decoded back to linear gray) of a random crop."""
    k = be.rasterize(traj, 2 * radius + 1)
    m = radius + 2
    h, w = gray_lin.shape
    y0 = int(rng.integers(0, h - tile - 2 * m + 1))
    x0 = int(rng.integers(0, w - tile - 2 * m + 1))
    crop = gray_lin[y0 : y0 + tile + 2 * m, x0 : x0 + tile + 2 * m]
    blur = cv2.filter2D(crop, -1, k)[m:-m, m:-m]
    noisy = blur + rng.normal(0.0, 1.0, blur.shape) * np.sqrt(0.002**2 + 0.0005 * blur)
    img8 = jpeg_roundtrip(encode_srgb8(np.clip(noisy, 0, 1)), jpeg)
    return decode_srgb8(img8).astype(np.float64)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--images", type=Path, default=DEFAULT_IMAGES)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--tile", type=int, default=128)
    ap.add_argument("--radius", type=int, default=60)
    ap.add_argument("--length", default="10,55", help="blur length range, px")
    ap.add_argument("--bow", type=float, default=0.15, help="largest control-point offset / L")
    ap.add_argument("--jpeg", type=int, default=90, help="JPEG quality (0: none)")
    ap.add_argument("--taper", type=float, default=be.DEFAULT_TAPER, help="cycles/px (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    lo, hi = (float(v) for v in args.length.split(","))
    rng = np.random.default_rng(args.seed)
    names = [p for p in list_images(args.images) if split_of(p) == "test"]
    picks = rng.choice(len(names), size=args.n, replace=len(names) < args.n)
    rows = []
    for i, idx in enumerate(picks):
        bgr = load_image(args.images, names[int(idx)])
        lin = decode_srgb8(bgr).astype(np.float64) @ np.array([0.0722, 0.7152, 0.2126])
        L, th = rng.uniform(lo, hi), rng.uniform(0.0, np.pi)
        d = L * np.array([np.cos(th), np.sin(th)])
        bow = rng.uniform(-args.bow, args.bow) * L if i % 2 else 0.0
        ctrl = 0.5 * d + 2 * bow * np.array([-np.sin(th), np.cos(th)])
        traj = bezier(np.zeros(2), ctrl, d)
        tile = sample(lin, traj, args.tile, args.radius, rng, args.jpeg)
        jp = args.taper if args.taper > 0 else None
        est = be.estimate_blur_vector(tile, radius=args.radius, taper=jp, min_margin=-1.0)
        tmap = be.tile_cepstrum(tile, args.radius, jp)
        n = be.fft_size(tile.shape)
        size = 2 * args.radius + 1

        def score(t: np.ndarray, tmap=tmap, n=n, size=size, jp=jp) -> float:
            k = be.rasterize(t, size)
            return be.kernel_score(tmap, be.kernel_cepstrum(k, args.radius, n, jp))

        c = traj.mean(axis=0)
        rows.append(
            {
                "image": names[int(idx)],
                "true_vector_px": d.round(3).tolist(),
                "bow_px": round(float(bow), 3),
                "estimate_px": None if est is None else list(est.vector_px),
                "estimate_score_margin": None if est is None else [est.score, est.margin],
                "endpoint_error_px": None
                if est is None
                else float(be.endpoint_difference(np.array(est.vector_px), d)),
                "score_true": score(traj),
                "score_rot90": score((traj - c) @ np.array([[0.0, 1.0], [-1.0, 0.0]])),
                "score_first_half": score(traj[: traj.shape[0] // 2]),
                "score_1.3x_long": score(1.3 * traj),
            }
        )
    ok = [r for r in rows if r["endpoint_error_px"] is not None]
    err = np.array([r["endpoint_error_px"] for r in ok])
    length = np.array([np.hypot(*r["true_vector_px"]) for r in ok])
    bowed = np.array([r["bow_px"] for r in ok])
    st = np.array([r["score_true"] for r in rows])
    res = {
        "n": len(rows),
        "undetermined": len(rows) - len(ok),
        "tile_px": args.tile,
        "radius_px": args.radius,
        "length_px": [lo, hi],
        "endpoint_error_px": {
            "median": float(np.median(err)),
            "p90": float(np.percentile(err, 90)),
            "share_under_2px": float(np.mean(err < 2)),
            "share_under_10pct_of_length": float(np.mean(err < 0.1 * length)),
        },
        "straight_only_median_px": float(np.median(err[bowed == 0])),
        "curved_only_median_px": float(np.median(err[bowed != 0])),
        "score_true_median": float(np.median(st)),
        "controls": {
            k: {
                "median": float(np.median([r[k] for r in rows])),
                "share_true_higher": float(np.mean(st > np.array([r[k] for r in rows]))),
            }
            for k in ("score_rot90", "score_first_half", "score_1.3x_long")
        },
        "samples": rows,
    }
    return emit(res, args.out, indent=1)


if __name__ == "__main__":
    sys.exit(main())
