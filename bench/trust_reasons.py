"""What each ``reason`` of the trust rules costs and buys, against simulator truth (prints JSON).

For each preset and seed (sessions simulated as ``bench/bench_detect.py`` does, in the same
work folder): detect, then cross every detection's ``reason`` with the truth. A detection is
*right* when both its ends lie within 2 px of one true streak's (either orientation; issue 45's
gate, ``bench_detect.TRUST_GATE_PX``), *wrong* otherwise. Per reason:

- ``detections``, ``right``, ``wrong``: for ``ok`` the wrong ones are the precision lost; for
  any other reason the right ones are correct streaks the rule rejects and the wrong ones the
  errors it catches;
- ``coverage_lost``: true inside streaks whose only right detections carry this reason (what
  ok-coverage would gain if the rule let them through), as a share of the true inside streaks
  in ``coverage_lost_pct``.

With a gyro, ``residual_caps``: the ``quality_ok`` streaks whose ``gyro_residual_px`` (the
check's vector residual) is at most each cap (unchecked streaks left out), their count,
wrong ones, ok-precision and ok-coverage (%): the trade a user makes who calibrates from a
stricter subset than ``quality_ok``.

Usage: ``python bench/trust_reasons.py --presets hard --seeds 1 2 --frames 10``;
``--tables DIR`` also writes each session's table with the truth columns ``right`` and
``end_error_px`` (Parquet, named for the session's folder, so that a preset file's table lands
in ``DIR`` too) for a closer look.
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

from bench_detect import TRUST_GATE_PX, simulate, truth_arrays, worse_end_distance  # noqa: E402
from json_out import emit  # noqa: E402

from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.separation.quality import REASONS  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402


def truth_columns(table: pd.DataFrame, truth: dict[str, Any]) -> tuple[pd.DataFrame, int]:
    """``table`` with ``end_error_px`` (the worse end's distance to the nearest true streak's,
    either orientation; NaN: no truth in the frame), ``right`` (within the gate) and
    ``truth_id`` (that streak's index in the frame, inside streaks only, else -1); and the
    number of true inside streaks."""
    out = table.copy()
    err = np.full(len(out), np.nan)
    tid = np.full(len(out), -1, np.int64)
    frames = out["frame"].to_numpy()
    n_inside = 0
    for fr in truth["frames"]:
        S, E, inside, _ = truth_arrays(fr)
        n_inside += int(inside.sum())
        rows = np.flatnonzero(frames == fr["index"])
        if rows.size == 0 or len(S) == 0:
            continue
        s = out[["start_x", "start_y"]].to_numpy(float)[rows]
        e = out[["end_x", "end_y"]].to_numpy(float)[rows]
        d = worse_end_distance(s, e, S, E)
        j = np.argmin(d, axis=1)
        err[rows] = d[np.arange(rows.size), j]
        tid[rows] = np.where(inside[j], j, -1)
    out["end_error_px"] = err
    out["right"] = err <= TRUST_GATE_PX
    out["truth_id"] = tid
    return out, n_inside


def _truth_keys(table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Each detection's true streak as one key (frame and ``truth_id``), and whether it is a
    right detection of a true inside streak (what ok-coverage counts)."""
    key = table["frame"].to_numpy(np.int64) * 100000 + table["truth_id"].to_numpy(np.int64)
    hit = table["right"].to_numpy(bool) & (table["truth_id"].to_numpy() >= 0)
    return key, hit


def reason_table(table: pd.DataFrame, n_inside: int) -> dict[str, dict[str, float]]:
    """Per reason: detections, right, wrong, coverage_lost (and its share in %)."""
    rows: dict[str, dict[str, float]] = {}
    right = table["right"].to_numpy(bool)
    reason = table["reason"].to_numpy(object)
    key, hit = _truth_keys(table)
    covered = set(key[hit & (reason == "ok")].tolist())
    for r in REASONS:
        m = reason == r
        lost = set(key[hit & m].tolist()) - covered
        if r == "ok":
            lost = set()
        rows[r] = {
            "detections": int(m.sum()),
            "right": int((m & right).sum()),
            "wrong": int((m & ~right).sum()),
            "coverage_lost": len(lost),
            "coverage_lost_pct": round(100.0 * len(lost) / max(n_inside, 1), 2),
        }
    rows["_all"] = {
        "inside_truth": n_inside,
        "ok_precision_pct": round(
            100.0 * rows["ok"]["right"] / max(rows["ok"]["detections"], 1), 2
        ),
        "ok_coverage_pct": round(100.0 * len(covered) / max(n_inside, 1), 2),
    }
    return rows


#: The residual caps (px) of :func:`residual_caps`: the check's default tolerance and below.
RESIDUAL_CAPS = (1.5, 1.0, 0.75, 0.5)


def residual_caps(
    table: pd.DataFrame, n_inside: int, caps: tuple[float, ...] = RESIDUAL_CAPS
) -> dict[str, dict[str, float]]:
    """Per cap (px, as text): the ``quality_ok`` streaks of ``table`` (with
    :func:`truth_columns`' ``right`` and ``truth_id``) whose ``gyro_residual_px`` is at most
    the cap: ``detections``, ``wrong``, ``ok_precision_pct`` and ``ok_coverage_pct`` (true
    inside streaks matched by one of them). Unchecked streaks (NaN) count under no cap."""
    ok = table["quality_ok"].to_numpy(bool)
    right = table["right"].to_numpy(bool)
    residual = table["gyro_residual_px"].to_numpy(float)
    key, hit = _truth_keys(table)
    out: dict[str, dict[str, float]] = {}
    for cap in caps:
        with np.errstate(invalid="ignore"):
            m = ok & (residual <= cap)
        n = int(m.sum())
        out[f"{cap:g}"] = {
            "detections": n,
            "wrong": int((m & ~right).sum()),
            "ok_precision_pct": round(100.0 * int((m & right).sum()) / max(n, 1), 2),
            "ok_coverage_pct": round(100.0 * len(set(key[m & hit].tolist())) / max(n_inside, 1), 2),
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--gyro", default="auto", choices=("auto", "off"))
    ap.add_argument("--work", type=Path, default=ROOT / "bench_out" / "detect")
    ap.add_argument("--tables", type=Path, default=None, help="write the tables here")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    runs = []
    for preset in args.presets:
        for seed in args.seeds:
            folder = simulate(args.work, preset, args.frames, seed)
            session = load_session(folder)
            res = detect_session(session, DetectParams(), gyro=args.gyro)
            table, n_inside = truth_columns(res.table, session.truth or {"frames": []})
            if args.tables is not None:
                args.tables.mkdir(parents=True, exist_ok=True)
                table.drop(columns=["centerline", "profile"]).to_parquet(
                    args.tables / f"{folder.name}.parquet"
                )
            runs.append(
                {
                    "preset": preset,
                    "seed": seed,
                    "reasons": reason_table(table, n_inside),
                    "residual_caps": residual_caps(table, n_inside),
                }
            )
    return emit({"runs": runs}, args.out)


if __name__ == "__main__":
    sys.exit(main())
