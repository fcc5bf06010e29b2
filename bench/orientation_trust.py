"""How far the orientation's confidence can be trusted, against simulator truth (prints JSON).

For each preset and seed (sessions simulated as ``bench/bench_detect.py`` does, in the same
work folder): detect (``--gyro off`` by default: the images alone, as where the gyro is
missing or set aside), then take every detection whose ends lie within 2 px of one true
streak's (either way round; issue 45's gate, ``bench_detect.TRUST_GATE_PX``) longer than 4 px,
and compare its start with the truth's. Per session, for all such detections and for the
``quality_ok`` ones:

- ``n``, ``wrong_pct``: how many, and the share whose start is the truth's end;
- ``log_loss``: the mean of ``-ln`` of the confidence given to the truth's start (a perfectly
  calibrated and sharp cue has the least);
- ``bins``: per confidence bin ``[lo, hi)``, ``[n, wrong]`` (a calibrated confidence ``c``
  is wrong on about ``1 - c`` of its bin);
- ``wrong_at_0_95``, ``wrong_at_0_99``: wrong starts claimed at least that sure.

Usage: ``python bench/orientation_trust.py --presets hard dense --seeds 1 2 --frames 10``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_detect import TRUST_GATE_PX, end_distances, simulate, truth_arrays  # noqa: E402
from json_out import emit  # noqa: E402

from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402

#: Confidence bins of the report.
BINS = ((0.5, 0.8), (0.8, 0.95), (0.95, 0.99), (0.99, 0.9999), (0.9999, 1.0 + 1e-12))
#: True streaks at most this long (px) have no start worth naming (ends within the gate).
MIN_TRUE_LENGTH_PX = 4.0


def oriented_against_truth(
    table: pd.DataFrame, truth: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(confidence, right, quality_ok)`` of the detections matched to a true streak (both
    ends within the gate, either orientation, the truth longer than
    :data:`MIN_TRUE_LENGTH_PX`); ``right``: the detection's start is the truth's."""
    conf: list[np.ndarray] = []
    right: list[np.ndarray] = []
    ok: list[np.ndarray] = []
    for fr in truth.get("frames", []):
        rows = table[table["frame"] == fr["index"]]
        S, E, _, _ = truth_arrays(fr)
        if not len(S) or not len(rows):
            continue
        a = rows[["start_x", "start_y"]].to_numpy(float)
        b = rows[["end_x", "end_y"]].to_numpy(float)
        same, swapped = end_distances(a, b, S, E)
        best = np.minimum(same, swapped)
        j = np.argmin(best, axis=1)
        i = np.arange(len(rows))
        use = (best[i, j] <= TRUST_GATE_PX) & (
            np.linalg.norm(E[j] - S[j], axis=1) > MIN_TRUE_LENGTH_PX
        )
        conf.append(rows["orientation_confidence"].to_numpy(float)[use])
        right.append((same[i, j] < swapped[i, j])[use])
        ok.append(rows["quality_ok"].to_numpy(bool)[use])
    if not conf:
        return np.zeros(0), np.zeros(0, bool), np.zeros(0, bool)
    return np.concatenate(conf), np.concatenate(right), np.concatenate(ok)


def calibration(conf: np.ndarray, right: np.ndarray) -> dict[str, Any]:
    """The report of one set of detections (module text)."""
    if conf.size == 0:
        return {"n": 0}
    p_truth = np.clip(np.where(right, conf, 1.0 - conf), 1e-9, 1.0)
    bins = {}
    for lo, hi in BINS:
        sel = (conf >= lo) & (conf < hi)
        bins[f"[{lo}, {min(hi, 1.0)})"] = [int(sel.sum()), int((sel & ~right).sum())]
    return {
        "n": int(conf.size),
        "wrong_pct": round(100.0 * float(np.mean(~right)), 2),
        "log_loss": round(float(-np.mean(np.log(p_truth))), 4),
        "bins": bins,
        "wrong_at_0_95": int(np.sum((conf >= 0.95) & ~right)),
        "wrong_at_0_99": int(np.sum((conf >= 0.99) & ~right)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--gyro", default="off", choices=("auto", "off"))
    ap.add_argument("--work", type=Path, default=ROOT / "bench_out" / "detect")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    runs = []
    for preset in args.presets:
        for seed in args.seeds:
            session = load_session(simulate(args.work, preset, args.frames, seed))
            res = detect_session(session, DetectParams(), gyro=args.gyro)
            conf, right, ok = oriented_against_truth(res.table, session.truth or {})
            runs.append(
                {
                    "preset": preset,
                    "seed": seed,
                    "gyro": args.gyro,
                    "all": calibration(conf, right),
                    "quality_ok": calibration(conf[ok], right[ok]),
                }
            )
    return emit({"runs": runs}, args.out)


if __name__ == "__main__":
    sys.exit(main())
