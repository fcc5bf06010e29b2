"""Benchmark: time to simulate 100 frames at 1280 x 720 on one core, and model agreement.

Prints JSON: per-preset wall time of ``write_session`` (rendering, noise, PNG, truth), the
median per-frame render time, and the same run's baseline (100 PNG encodes of a 1280 x 720
frame plus a Gaussian blur each, a fixed workload), so that ratios stay comparable on a noisy
machine. Per preset it also reports how far ``blurtrack.geometry.blur_model.BlurModel`` with the
TRUE
calibration lands from the true streak endpoints: with an ideal 1 kHz gyro (simulator/model
agreement) and with the preset's own gyro (the error floor that gyro noise, bias, scale and
sampling leave for calibration). Usage:
``PYTHONPATH=. python bench/bench_simulate.py [--frames 100] [--presets ...]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from blurtrack.geometry.blur_model import BlurModel  # noqa: E402
from blurtrack.geometry.gyro import GyroTrace  # noqa: E402
from rigs.sim.preset import SimPreset, get_preset  # noqa: E402
from rigs.sim.rig import SimRig  # noqa: E402
from rigs.sim.shake import default_shake_path  # noqa: E402
from rigs.sim.writer import write_session  # noqa: E402


def baseline(frames: int) -> float:
    """Seconds for ``frames`` x (Gaussian blur + PNG encode) of a 1280 x 720 uint8 image."""
    img = np.random.default_rng(0).integers(0, 40, (720, 1280), dtype=np.uint8)
    t = time.perf_counter()
    for _ in range(frames):
        cv2.imencode(".png", cv2.GaussianBlur(img, (7, 7), 1.5), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return time.perf_counter() - t


def endpoint_errors(preset: SimPreset, seed: int, frames: int = 10) -> dict[str, float]:
    """Endpoint errors (px) of BlurModel with the true calibration against the truth."""
    rig = SimRig(preset, seed, frames)
    t = rig.gyro_times_ns() * 1e-9
    model = BlurModel(rig.calibration, GyroTrace(t, rig.sample_gyro(t)))
    errs = []
    for i in range(frames):
        fr = rig.frame_truth(i)
        st = [x for x in fr["streaks"] if x["inside"]]
        start, end, _, _ = model.streak_endpoints(
            np.array([x["ref"] for x in st]),
            fr["t_ref_ns"] * 1e-9,
            fr["timestamp_ns"] * 1e-9,
            fr["exposure_ns"] * 1e-9,
        )
        errs.append(np.linalg.norm(start - [x["start"] for x in st], axis=1))
        errs.append(np.linalg.norm(end - [x["end"] for x in st], axis=1))
    e = np.concatenate(errs)
    return {
        "mean_px": round(float(e.mean()), 5),
        "median_px": round(float(np.median(e)), 5),
        "max_px": round(float(e.max()), 5),
        "endpoints": int(e.size),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--presets", nargs="+", default=["clean", "realistic", "hard"])
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    have_shake = default_shake_path().is_file()
    base = [baseline(args.frames)]
    results = {}
    for name in args.presets:
        preset = get_preset(name)
        if preset.motion == "shake" and not have_shake:
            preset = preset.replace(motion="synthetic")
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            rig = SimRig(preset, args.seed, args.frames)
            summary = write_session(rig, Path(tmp) / "s")
            total = time.perf_counter() - t
        # Per-frame render medians on a few frames again (in memory, no disk).
        per = []
        for ts in rig.frame_times_ns[:10]:
            t = time.perf_counter()
            rig.render_frame(int(ts) * 1e-9)
            per.append(time.perf_counter() - t)
        base.append(baseline(args.frames))
        ideal = preset.replace(
            gyro_noise_radps=0.0, gyro_bias_radps=0.0, gyro_scale_error=0.0, imu_rate_hz=1000.0
        )
        results[name] = {
            "motion": preset.motion,
            "frames": args.frames,
            "resolution": [preset.width, preset.height],
            "total_s": round(total, 3),
            "render_s": round(summary["seconds"]["render"], 3),
            "truth_s": round(summary["seconds"]["truth"], 3),
            "median_frame_render_s": round(statistics.median(per), 4),
            "streaks": summary["streaks"],
            "median_streak_px": round(summary["streak_length_px"]["median"], 2),
            "true_calibration_endpoint_error": {
                "ideal_1khz_gyro": endpoint_errors(ideal, args.seed),
                "preset_gyro": endpoint_errors(preset, args.seed),
            },
        }
    b = statistics.median(base)
    for r in results.values():
        r["ratio_to_baseline"] = round(r["total_s"] / b, 2)
    print(
        json.dumps(
            {
                "benchmark": "simulate",
                "single_core": True,
                "baseline_png_s_median": round(b, 3),
                "baseline_runs": len(base),
                "target": "well under 60 s per 100 frames at 1280x720",
                "presets": results,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
