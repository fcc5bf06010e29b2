"""Natural-scene calibration benchmark: simulated textured far scenes (rigs.sim.natural),
``blurtrack calibrate`` timed as a whole command, errors against the simulator's truth.

Prints JSON: per gyro rate, medians over seeds of |error| (offset, readout, fx/fy relative,
cx/cy, rotation), how often the axis search picked the true permutation, the share of
estimates with the truth inside 3 sigma, and the command's wall and CPU time (with the
wall time's ratio to the video's duration, the baseline of a real-time calibration).
``--depth-m``/``--speed-mps`` simulate driving towards a plane (the translation nuisance);
``--fit`` overrides the natural default; ``--translation`` is passed to calibrate.

    .venv/bin/python bench/bench_natural.py --seeds 3 --frames 60 --width 640 --height 360
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rigs.sim.natural import NaturalRig
from rigs.sim.preset import NOMINAL_R_CAM_IMU, get_preset
from rigs.sim.writer import write_session

KEYS = ("timeshift_s", "readout_s", "fx", "fy", "cx", "cy", "rot_x", "rot_y", "rot_z")


def one(root: Path, seed: int, rate: float, args: argparse.Namespace) -> dict:
    preset = get_preset("realistic").replace(
        width=args.width,
        height=args.height,
        focal_px=1000.0 * args.width / 1280,
        imu_rate_hz=rate,
    )
    sess = Path(args.sessions or root) / f"s{seed}_{int(rate)}"
    drive = (
        dict(depth_m=args.depth_m, speed_mps=args.speed_mps, speed_wobble=0.3)
        if args.depth_m
        else {}
    )
    if not (args.sessions and (sess / "truth.yaml").exists()):  # --sessions: reuse
        write_session(NaturalRig(preset, seed, args.frames, **drive), sess)
    out = root / f"c{seed}_{int(rate)}" / "calib.yaml"
    cmd = [sys.executable, "-m", "blurtrack", "calibrate", str(sess), "--out", str(out)]
    cmd += ["--translation", args.translation] + (["--fit", args.fit] if args.fit else [])
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    rec: dict = {"seed": seed, "rate_hz": rate, "wall_s": wall, "cpu_s": cpu, "rc": proc.returncode}
    summ = out.with_name("calib.summary.json")
    if not summ.exists():
        rec["error"] = proc.stderr.strip()[-300:]
        return rec
    d = json.loads(summ.read_text())
    err, sig, tru = d["error_vs_truth"], d["sigma"], d["truth"]
    rec["axes_correct"] = bool(np.allclose(d["axes"]["winner"]["R_cam_imu"], NOMINAL_R_CAM_IMU))
    rec["axes_margin"] = d["axes"]["margin"]
    rec["abs_error"] = {k: abs(err[k]) for k in KEYS}
    rec["abs_error"]["fx_rel"] = abs(err["fx"]) / tru["fx"]
    rec["abs_error"]["fy_rel"] = abs(err["fy"]) / tru["fy"]
    rec["abs_error"]["rotation_deg"] = math.degrees(
        math.sqrt(sum(err[k] ** 2 for k in ("rot_x", "rot_y", "rot_z")))
    )
    rec["in_3sigma"] = [abs(err[k]) <= 3 * sig[k] for k in KEYS if k in sig]
    rec["status"] = d["status"]
    rec["translation"] = (d.get("translation") or {}).get("mode")
    # the simulator's gyro scale/cross-axis matrix: unfitted by default, it biases the focal
    # lengths and the rotation (docs/natural.md)
    rec["true_scale"] = {k: tru[k] for k in tru if k.startswith("scale_")}
    return rec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--rates", default="200,1000")
    ap.add_argument("--depth-m", type=float, default=None, help="driving: plane distance")
    ap.add_argument("--speed-mps", type=float, default=3.0, help="driving: forward speed")
    ap.add_argument("--translation", default="auto", choices=("none", "auto", "per-pair", "travel"))
    ap.add_argument("--fit", default=None, help="--fit for calibrate (default: natural's)")
    ap.add_argument("--seed-list", default=None, help="comma-separated seeds (overrides --seeds)")
    ap.add_argument("--sessions", default=None, help="keep sessions here as s<seed>_<rate>, reuse")
    args = ap.parse_args()
    out: dict = {"config": vars(args), "rates": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (float(r) for r in args.rates.split(",")):
            recs = []
            seeds = [int(x) for x in args.seed_list.split(",")] if args.seed_list else None
            for s in seeds if seeds is not None else range(args.seeds):
                recs.append(one(Path(tmp), s, rate, args))
                print(json.dumps(recs[-1]), file=sys.stderr, flush=True)  # partial results
            ok = [r for r in recs if "abs_error" in r]
            med = (
                {k: float(np.median([r["abs_error"][k] for r in ok])) for k in ok[0]["abs_error"]}
                if ok
                else {}
            )
            flags = [f for r in ok for f in r["in_3sigma"]]
            wall = float(np.median([r["wall_s"] for r in recs]))
            cpu = float(np.median([r["cpu_s"] for r in recs]))
            out["rates"][str(int(rate))] = {
                "runs": len(recs),
                "calibrated": len(ok),
                "median_abs_error": med,
                "axes_correct": sum(r["axes_correct"] for r in ok),
                "truth_in_3sigma": float(np.mean(flags)) if flags else None,
                "median_wall_s": wall,
                "median_cpu_s": cpu,
                "translation": [r.get("translation") for r in recs],
                "wall_over_video_duration": wall / (args.frames / 30.0),
                "records": recs,
            }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
