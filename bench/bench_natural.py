"""Natural-scene calibration benchmark: simulated textured far scenes (rigs.sim.natural),
``blurtrack calibrate`` timed as a whole command, errors against the simulator's truth.

Prints JSON: per gyro rate, medians over seeds of |error| (offset, readout, fx/fy relative,
cx/cy, rotation), how often the axis search picked the true permutation, the share of
estimates with the truth inside 3 sigma, and the command's wall time (with its ratio to the
video's duration, the baseline of a real-time calibration).

    .venv/bin/python bench/bench_natural.py --seeds 3 --frames 60 --width 640 --height 360
"""

from __future__ import annotations

import argparse
import json
import math
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
    sess = root / f"s{seed}_{int(rate)}"
    write_session(NaturalRig(preset, seed, args.frames), sess)
    out = root / f"c{seed}_{int(rate)}" / "calib.yaml"
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "blurtrack", "calibrate", str(sess), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    rec: dict = {"seed": seed, "rate_hz": rate, "wall_s": wall, "rc": proc.returncode}
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
    return rec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--rates", default="200,1000")
    args = ap.parse_args()
    out: dict = {"config": vars(args), "rates": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (float(r) for r in args.rates.split(",")):
            recs = [one(Path(tmp), s, rate, args) for s in range(args.seeds)]
            ok = [r for r in recs if "abs_error" in r]
            med = (
                {k: float(np.median([r["abs_error"][k] for r in ok])) for k in ok[0]["abs_error"]}
                if ok
                else {}
            )
            flags = [f for r in ok for f in r["in_3sigma"]]
            wall = float(np.median([r["wall_s"] for r in recs]))
            out["rates"][str(int(rate))] = {
                "runs": len(recs),
                "calibrated": len(ok),
                "median_abs_error": med,
                "axes_correct": sum(r["axes_correct"] for r in ok),
                "truth_in_3sigma": float(np.mean(flags)) if flags else None,
                "median_wall_s": wall,
                "wall_over_video_duration": wall / (args.frames / 30.0),
                "records": recs,
            }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
