"""The natural fit's treatments of the unfitted gyro scale on the same tracks, against the
simulator's truth (docs/journal/natural.md, "Gyro scale under a prior").

For each kept session of ``bench/bench_natural.py --root DIR --keep`` (``r{seed}_{rate}``):
``calibrate_natural(..., translation="none", scale_prior="consider")`` once (tracking, axis
search, equal-blur passes), then on its final tracks

- ``consider``: that fit (scale at the identity, the consider term in sigma);
- ``map``: :func:`calib.natural.scale.with_scale_prior` (the default of ``blurtrack calibrate``);
- ``known``: :func:`calib.fit.calibrate` from the true scale matrix (a reference only).

Prints JSON: per gyro rate and treatment, the issue 13 target counts, medians and the share
of estimates with the truth inside 3 sigma (the keys of ``natural_common.KEYS``).

    PYTHONPATH=. .venv/bin/python bench/bench_natural_scale.py --root DIR --sessions all
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
from natural_common import KEYS, TARGETS

from blurtrack.geometry.calibration import Calibration
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.session import load_session
from calib.fit import FitOptions, calibrate
from calib.natural.cli import NATURAL_FIT
from calib.natural.pipeline import calibrate_natural
from calib.natural.scale import with_scale_prior
from calib.params import rotation_error_rad

TREATMENTS = ("consider", "map", "known")


def score(cal: Calibration, sigma: dict[str, float], truth: Calibration, R_true: np.ndarray):
    """|error| in the benchmark's terms and the 3-sigma flags of ``KEYS``."""
    k, kt = cal.camera.intrinsics, truth.camera.intrinsics
    rv = rotation_error_rad(cal.R_cam_imu, R_true)
    err = {
        "timeshift_s": cal.timeshift_cam_imu_s - truth.timeshift_cam_imu_s,
        "readout_s": cal.camera.readout_s - truth.camera.readout_s,
        **{n: k[i] - kt[i] for i, n in enumerate(("fx", "fy", "cx", "cy"))},
        **{n: float(rv[i]) for i, n in enumerate(("rot_x", "rot_y", "rot_z"))},
    }
    ae = {n: abs(v) for n, v in err.items()}
    ae["fx_rel"], ae["fy_rel"] = ae["fx"] / kt[0], ae["fy"] / kt[1]
    ae["rotation_deg"] = math.degrees(float(np.linalg.norm(rv)))
    z = {n: err[n] / sigma[n] for n in KEYS if n in sigma}
    return {"abs_error": ae, "z": z, "in_3sigma": [abs(v) <= 3 for v in z.values()]}


def run_session(folder: Path) -> dict[str, Any]:
    s = load_session(folder)
    if not s.truth:
        raise SystemExit(f"error: {folder} has no truth.yaml")
    truth = calibration_from_dict(s.truth["calibration"], source="truth.yaml")
    M: np.ndarray = np.asarray(s.truth["simulator"]["gyro"]["scale_matrix"], dtype=np.float64)
    U, _, Vt = np.linalg.svd(M)
    R_true = truth.R_cam_imu @ (U @ Vt).T
    nat = calibrate_natural(
        s, FitOptions(fit=NATURAL_FIT), translation="none", scale_prior="consider"
    )
    res, gyro = nat.result, s.gyro()
    opts = FitOptions(fit=NATURAL_FIT, shift_window_s=0.02, residuals="endpoints")
    m, _ = with_scale_prior(res, nat.streaks, gyro, opts)
    kn = calibrate(nat.streaks, gyro, res.initial.with_(gyro_scale_matrix=M), opts)
    return {
        "consider": score(res.calibration, res.sigma, truth, R_true),
        "map": score(m.calibration, m.sigma, truth, R_true),
        "known": score(kn.calibration, kn.sigma, truth, R_true),
    }


def summarise(recs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for t in TREATMENTS:
        rs = [r[t] for r in recs]
        out[t] = {
            "targets": {
                name: f"{sum(r['abs_error'][key] <= lim for r in rs)}/{len(rs)}"
                for name, key, lim in TARGETS
            },
            "median_abs_error": {
                k: float(np.median([r["abs_error"][k] for r in rs]))
                for k in ("fx_rel", "fy_rel", "cx", "cy", "rotation_deg")
            },
            "truth_in_3sigma": float(np.mean([f for r in rs for f in r["in_3sigma"]])),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", type=Path, required=True, help="bench_natural.py --root --keep")
    ap.add_argument("--sessions", default="all", help="r0_200,r1_1000 or all")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args()
    if args.out is not None and args.out.exists():
        raise SystemExit(f"error: {args.out} exists; not overwriting it")
    if args.sessions == "all":
        folders = sorted(p for p in args.root.glob("r*_*") if (p / "truth.yaml").is_file())
    else:
        folders = [args.root / t for t in args.sessions.split(",")]
    records: dict[str, dict[str, Any]] = {}
    for f in folders:
        records[f.name] = run_session(f)
        brief = {t: records[f.name][t]["abs_error"] for t in TREATMENTS}
        print(f.name, json.dumps(brief), file=sys.stderr, flush=True)
    rates = sorted({n.rsplit("_", 1)[1] for n in records}, key=int)
    res = {
        "cases": {
            f"rotation@{r}": summarise([v for n, v in records.items() if n.endswith(f"_{r}")])
            for r in rates
        },
        "records": records,
    }
    text = json.dumps(res, indent=2)
    if args.out is not None:
        args.out.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
