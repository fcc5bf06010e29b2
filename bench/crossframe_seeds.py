"""How well the gyro carries one frame's streaks to another frame (prints JSON); issue 14.

Every frame of a laser-wall session shows the same wall dots. A streak's time midpoint in
frame ``j`` (the dot at its row's mid-exposure), carried by the blur model to frame ``k`` (a
fixed point over the rolling shutter's rows: the row, hence the time, follows the dot), is a
prediction of where that dot's streak has its time midpoint in frame ``k``: a seed for a joint
placement where the template pass cannot tell the dots of a chain apart (docs/journal/detection.md,
"Session 2026-12-04, second"). Measured against the simulator's truth (the same dot, by its
``dot`` index):

- ``raw``: the carried midpoints against the true ones (the session's nominal calibration with
  the detector's refined time shift and readout, as the template pass uses it);
- ``corrected``: after a per-pair affine correction that a detector could fit itself (no
  truth): the displacement supported by most carried points within 2 px of one of frame
  ``k``'s own unclipped detections, then an affine fit to the nearest-neighbour pairs within
  4 px, then 2 px;
- ``missed_seeded``: of frame ``k``'s true inside dots that its detections miss (the bench's
  Hungarian match, gate 4 px), the share with a corrected seed within 2 px of the true
  midpoint.

Usage: ``python bench/crossframe_seeds.py SESSION [--table T.parquet] [--offsets 1 2]``
(without ``--table`` the session is detected here, as ``bench/bench_detect.py`` does).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_detect import match, truth_arrays  # noqa: E402
from json_out import emit  # noqa: E402

from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.geometry.blur_model import BlurModel  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402

#: A source streak is the truth's dot whose midpoint lies within this (px) of its own.
SOURCE_MATCH_PX = 2.0
#: A seed "hits" a missed dot within this (px).
SEED_HIT_PX = 2.0
#: The correction's candidate displacements: pairs within this (px); their support radius.
SEARCH_PX = 30.0
SUPPORT_PX = 2.0
#: The affine refits' nearest-neighbour gates (px), in turn.
AFFINE_GATES_PX = (4.0, 2.0)
MIN_PAIRS = 6


def carry(model: BlurModel, p: np.ndarray, tj: tuple[float, float], tk: tuple[float, float]):
    """Midpoints ``p (N, 2)`` of frame ``tj = (t_s, exposure_s)`` carried to frame ``tk``."""
    cam = model.camera
    H = float(cam.height)
    t_ref = tj[0] + cam.readout_s * np.clip(p[:, 1], 0, H - 1) / H + 0.5 * tj[1]
    q = p.copy()
    for _ in range(3):
        t = tk[0] + cam.readout_s * np.clip(q[:, 1], 0, H - 1) / H + 0.5 * tk[1]
        q = np.asarray(model.point_track(p, t_ref, t[:, None]))[:, 0]
    return q


def correct(pred: np.ndarray, own: np.ndarray) -> np.ndarray | None:
    """``pred`` corrected by an affine map fitted to frame ``k``'s own detections ``own``
    (module text); None with too few pairs."""
    if len(own) < MIN_PAIRS or len(pred) < MIN_PAIRS:
        return None
    D = np.linalg.norm(pred[:, None] - own[None], axis=2)
    ii, jj = np.nonzero(D < SEARCH_PX)
    if ii.size == 0:
        return None
    disp = own[jj] - pred[ii]
    # The displacement most pairs agree with (a dot grid has ~50 px spacing: the right one
    # is the mode, the others scatter).
    step = max(1, disp.shape[0] // 400)
    support = [np.sum(np.linalg.norm(disp - d, axis=1) < SUPPORT_PX) for d in disp[::step]]
    q = pred + disp[::step][int(np.argmax(support))]
    for gate in AFFINE_GATES_PX:
        D = np.linalg.norm(q[:, None] - own[None], axis=2)
        j = D.argmin(axis=1)
        ok = D[np.arange(len(q)), j] < gate
        if ok.sum() < MIN_PAIRS:
            return None
        A = np.c_[pred[ok], np.ones(int(ok.sum()))]
        coef, *_ = np.linalg.lstsq(A, own[j[ok]], rcond=None)
        q = np.c_[pred, np.ones(len(pred))] @ coef
    return q


def _median(v: list[float]) -> float | None:
    return float(np.median(v)) if v else None


def _stats(err: np.ndarray) -> dict[str, float | int]:
    if err.size == 0:
        return {"n": 0}
    return {
        "n": int(err.size),
        "median_px": float(np.median(err)),
        "p90_px": float(np.percentile(err, 90)),
    }


def pair(
    model: BlurModel,
    truth: dict[str, Any],
    tab: pd.DataFrame,
    times: list[tuple[float, float]],
    j: int,
    k: int,
) -> dict[str, Any]:
    """The measures of the module text for frames ``j`` (source) and ``k``."""
    frames = truth["frames"]
    src = tab[(tab.frame == j) & ~tab.clipped][["mid_x", "mid_y"]].to_numpy()
    own_k = tab[(tab.frame == k) & ~tab.clipped]
    own = own_k[["mid_x", "mid_y"]].to_numpy()
    mid_j = np.array([s["mid"] for s in frames[j]["streaks"]], float).reshape(-1, 2)
    dot_j = np.array([s["dot"] for s in frames[j]["streaks"]])
    mid_k = np.array([s["mid"] for s in frames[k]["streaks"]], float).reshape(-1, 2)
    dot_k = {int(d): i for i, d in enumerate(s["dot"] for s in frames[k]["streaks"])}
    if src.size == 0 or mid_j.size == 0:
        return {"source": j, "target": k, "sources": len(src)}
    pred = carry(model, src, times[j], times[k])
    q = correct(pred, own)
    # Source streaks that are one true dot: their dot's true midpoint in frame k.
    D = np.linalg.norm(src[:, None] - mid_j[None], axis=2)
    near = D.argmin(axis=1)
    is_dot = D[np.arange(len(src)), near] < SOURCE_MATCH_PX
    ids = [dot_k.get(int(dot_j[i]), -1) for i in near]
    has = is_dot & (np.array(ids) >= 0)
    true_k = mid_k[np.array(ids)[has]]
    out: dict[str, Any] = {
        "source": j,
        "target": k,
        "sources": len(src),
        "raw": _stats(np.linalg.norm(pred[has] - true_k, axis=1)),
    }
    if q is None:
        out["corrected"] = {"n": 0}
        return out
    out["corrected"] = _stats(np.linalg.norm(q[has] - true_k, axis=1))
    # Frame k's missed true inside dots, and whether a corrected seed lies on them.
    S, E, inside, _ = truth_arrays(frames[k])
    a = own_k[["start_x", "start_y"]].to_numpy()
    b = own_k[["end_x", "end_y"]].to_numpy()
    _, _, cols, _ = match(a, b, S, E)
    missed = np.flatnonzero(inside & ~np.isin(np.arange(len(S)), cols))
    if missed.size:
        d = np.linalg.norm(mid_k[missed][:, None] - q[None], axis=2).min(axis=1)
        out["missed"] = int(missed.size)
        out["missed_seeded"] = float(np.mean(d < SEED_HIT_PX))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--table", type=Path, help="a `blurtrack detect` table with its summary")
    ap.add_argument("--offsets", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    session = load_session(args.session)
    if session.truth is None:
        print("crossframe_seeds: the session has no truth.yaml (simulated sessions only)")
        return 2
    if args.table is not None:
        tab = pd.read_parquet(args.table)
        summary = json.loads(args.table.with_suffix(".summary.json").read_text())
    else:
        res = detect_session(session, DetectParams(), workers=1)
        tab, summary = res.table, res.summary
    calib = session.initial_calibration()
    if summary.get("gyro_timeshift_s") is not None:
        calib = calib.with_(timeshift_cam_imu_s=float(summary["gyro_timeshift_s"]))
    if summary.get("gyro_readout_s") is not None:
        calib = calib.with_(readout_s=float(summary["gyro_readout_s"]))
    model = BlurModel(calib, session.gyro())
    n = len(session.frames)
    times = [
        (float(t), float(e))
        for t, e in zip(session.frame_times_s, session.exposures_s, strict=True)
    ]
    pairs = []
    for k in range(n):
        for off in args.offsets:
            for j in (k - off, k + off):
                if 0 <= j < n:
                    pairs.append(pair(model, session.truth, tab, times, j, k))
    by_offset = {}
    for off in args.offsets:
        # The pairs this far apart whose correction could be fitted: raw and corrected over
        # the same pairs; the missed dots' share over those of them with missed dots.
        sel = [
            p
            for p in pairs
            if abs(p["source"] - p["target"]) == off and p.get("corrected", {}).get("n")
        ]
        missed = [p["missed_seeded"] for p in sel if "missed_seeded" in p]
        by_offset[str(off)] = {
            "pairs": len(sel),
            "raw_median_of_medians_px": _median([p["raw"]["median_px"] for p in sel]),
            "corrected_median_of_medians_px": _median([p["corrected"]["median_px"] for p in sel]),
            "missed_seeded_median": _median(missed),
        }
    return emit({"session": str(args.session), "by_offset": by_offset, "pairs": pairs}, args.out)


if __name__ == "__main__":
    sys.exit(main())
