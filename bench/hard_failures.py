"""Failure classes of detection on simulated sessions against ``truth.yaml`` (prints JSON).

Issue 14 (docs/journal/detection.md, "Session 2026-12-03: failure classes on hard"). The session is
detected as ``bench/bench_detect.py`` does (``detect_session``, one process) with the second
pass's outcome recorded per frame; detections are matched to the truth exactly as the bench
does (Hungarian assignment, orientation-free mean endpoint distance, gate 4 px). Each *missed*
true inside streak and each *false* (unmatched, unclipped) detection is then classed by where
its ends lie on the true centre lines (``ON_LINE_PX``):

- ``fragment``: both ends of a detection on one true streak's centre line, its length under
  0.75 of the true length (missed: the true streak has such a piece);
- ``chain``: the detection's two ends on two different true streaks (merged dots);
- ``near``: the best detection within 4-10 px mean endpoint distance (wrong shape or ends);
- ``none`` (missed) / ``spurious`` (false): nothing of the above.

Counts are split by the frame's template-pass outcome (``skipped``, ``refused``,
``refined``) and per frame; the session's scanned time shift against the simulator's.

Usage: ``python bench/hard_failures.py /tmp/w/hard-s2-f10 [/tmp/w/hard-s3-f10 ...]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_detect import match, truth_arrays  # noqa: E402

import blurtrack.detect.gyro.refinepass as refinepass  # noqa: E402
from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402

NEAR_PX = 10.0
ON_LINE_PX = 3.0
FRAGMENT = 0.75


def _seg_dist(p: np.ndarray, line: np.ndarray) -> float:
    """Distance of point ``p`` from the polyline ``line`` ``(n, 2)``."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, 1) / np.maximum(np.sum(ab * ab, 1), 1e-12), 0, 1)
    return float(np.min(np.hypot(*(a + t[:, None] * ab - p).T)))


def classify(folder: Path, params: DetectParams | None = None) -> dict[str, Any]:
    session = load_session(folder)
    status: list[str] = []
    orig = refinepass.refine_frame

    def spy(*a: Any, **k: Any) -> Any:
        out, what = orig(*a, **k)
        status.append(what.status)
        return out, what

    refinepass.refine_frame = spy  # type: ignore[assignment]
    try:
        res = detect_session(session, params or DetectParams(), workers=1)
    finally:
        refinepass.refine_frame = orig  # type: ignore[assignment]
    truth = session.truth or {"frames": []}
    table = res.table
    missed: dict[str, dict[str, int]] = {}
    false: dict[str, dict[str, int]] = {}
    per_frame = []
    for k, fr in enumerate(truth["frames"]):
        st = fr.get("streaks") or []
        fstat = status[k] if k < len(status) else "uncovered"
        S, E, inside, L = truth_arrays(fr)
        lines = [np.asarray(s["centerline"], float).reshape(-1, 2) for s in st]
        d = table[table["frame"] == fr["index"]]
        s = d[["start_x", "start_y"]].to_numpy(float)
        e = d[["end_x", "end_y"]].to_numpy(float)
        clipped = d["clipped"].to_numpy(bool)
        dl = np.hypot(*(e - s).T) if len(d) else np.zeros(0)
        if len(d) and len(S):
            cost, r, c, _ = match(s, e, S, E)
        else:
            cost = np.full((len(d), len(S)), np.inf)
            r = c = np.zeros(0, int)
        matched_t = np.zeros(len(S), bool)
        matched_t[c] = True
        matched_d = np.zeros(len(d), bool)
        matched_d[r] = True
        # Which true line each detection end lies on (-1: none), the nearest one.
        on = np.full((len(d), 2), -1)
        for i in range(len(d)):
            for j, pnt in enumerate((s[i], e[i])):
                dist = [_seg_dist(pnt, ln) for ln in lines]
                if dist and min(dist) <= ON_LINE_PX:
                    on[i, j] = int(np.argmin(dist))
        m_cls = missed.setdefault(fstat, {})
        f_cls = false.setdefault(fstat, {})
        for t in np.flatnonzero(inside & ~matched_t):
            frag = np.any((on[:, 0] == t) & (on[:, 1] == t) & (dl < FRAGMENT * L[t]))
            chain = np.any(
                ((on[:, 0] == t) | (on[:, 1] == t)) & (on[:, 0] != on[:, 1]) & (on.min(1) >= 0)
            )
            near = len(d) > 0 and float(np.min(cost[:, t])) < NEAR_PX
            cls = "fragment" if frag else "chain" if chain else "near" if near else "none"
            m_cls[cls] = m_cls.get(cls, 0) + 1
        for i in np.flatnonzero(~clipped & ~matched_d).tolist():
            a, b = int(on[i, 0]), int(on[i, 1])
            if a >= 0 and a == b and dl[i] < FRAGMENT * L[a]:
                cls = "fragment"
            elif a >= 0 and b >= 0 and a != b:
                cls = "chain"
            elif len(S) and np.min(cost[i]) < NEAR_PX:
                cls = "near"
            else:
                cls = "spurious"
            f_cls[cls] = f_cls.get(cls, 0) + 1
        chord = np.array([np.hypot(*(ln[-1] - ln[0])) for ln in lines])
        arc = np.array([np.sum(np.hypot(*np.diff(ln, axis=0).T)) for ln in lines])
        per_frame.append(
            {
                "frame": fr["index"],
                "status": fstat,
                "true_inside": int(inside.sum()),
                "recall": float(np.sum(matched_t & inside) / max(inside.sum(), 1)),
                "precision": float(np.sum(matched_d & ~clipped) / max((~clipped).sum(), 1)),
                "true_arc_median_px": float(np.median(arc)) if arc.size else None,
                "chord_over_arc_median": float(np.median(chord / np.maximum(arc, 1e-9)))
                if arc.size
                else None,
            }
        )
    cal = truth.get("calibration", {}).get("cam0", {})
    return {
        "session": str(folder),
        "timeshift_scanned_s": res.summary.get("gyro_timeshift_s"),
        "timeshift_true_s": cal.get("timeshift_cam_imu"),
        "template_frames": res.summary.get("gyro_template_frames"),
        "missed": missed,
        "false": false,
        "frames": per_frame,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--params", type=Path, default=None)
    args = ap.parse_args()
    params = DetectParams.from_yaml(args.params) if args.params is not None else None
    out = [classify(f, params) for f in args.folders]
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
