"""Failure modes of the lights *not* found whole on the real photographs (prints JSON).

Issue 14 (docs/journal/detection.md, "Failure modes of the lights not found whole"). Against the
photograph's whole-component reference vector (``bench/real_streaks.py``), each streak is
classed: ``clipped``; ``whole`` (within the shape tolerance of the reference, either sign);
``fragment`` (its start-to-end length under 0.75 of the reference's); ``chain`` (over 1.25);
else ``wrong_vector`` (similar length, wrong direction: a line from one light's hook to its
neighbour's foot, or glare). Counts are split by saturation and by whether the streak lies
in the two uncountable bushes of night2 (boxes by eye). ``joinable_pairs``: disjoint pairs of
non-whole streaks whose nearest ends lie within ``gap`` px and whose farthest ends give a
vector within the tolerance of the reference (what joining detected fragments could gain).

Usage: ``python bench/real_failures.py``
"""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from real_streaks import DATA, whole_reference  # noqa: E402

from blurtrack.detect import DetectParams, detect_frame  # noqa: E402
from blurtrack.detect.separation.consensus import shape_tolerance  # noqa: E402
from blurtrack.detect.session.orientation import combine  # noqa: E402
from blurtrack.detect.session.table import build_table, frame_rows  # noqa: E402

#: night2's two bushes (full-size pixels, x0, x1, y0, y1), by eye.
BUSHES = ((142, 250, 425, 625), (308, 417, 425, 625))


def joinable(ends: np.ndarray, ref: np.ndarray, tol: float, gap: float) -> int:
    """Disjoint pairs (greedy, best first) of ``ends`` ``(n, 2, 2)`` joinable onto ``ref``."""
    cand = []
    for i, j in itertools.combinations(range(len(ends)), 2):
        if np.min(np.hypot(*(ends[i][:, None] - ends[j][None]).reshape(-1, 2).T)) > gap:
            continue
        pts = np.concatenate([ends[i], ends[j]])
        dev = min(
            min(np.hypot(*(pts[b] - pts[a] - ref)), np.hypot(*(pts[b] - pts[a] + ref)))
            for a, b in itertools.combinations(range(4), 2)
        )
        if dev <= tol:
            cand.append((dev, i, j))
    used: set[int] = set()
    n = 0
    for _, i, j in sorted(cand):
        if i not in used and j not in used:
            used |= {i, j}
            n += 1
    return n


def classify(name: str) -> dict:
    img = cv2.imread(str(DATA / f"{name}.jpg"), cv2.IMREAD_UNCHANGED)
    fs = detect_frame(img)
    t = build_table([frame_rows(0, 0, fs, combine(np.zeros((len(fs), 3))))])
    ref = whole_reference(img, fs.sigma_c_px)
    start = t[["start_x", "start_y"]].to_numpy()
    end = t[["end_x", "end_y"]].to_numpy()
    v = end - start
    if ref is None:  # no modal cluster: the median unflagged length stands in
        ok = ~(t.clipped | t.crossing | t.looped).to_numpy()
        length, whole = float(np.median(np.hypot(*v[ok].T))), np.zeros(len(t), bool)
        tol = np.inf
    else:
        length, tol = (
            float(np.hypot(*ref)),
            float(shape_tolerance(ref[None], DetectParams().quality)[0]),
        )
        dev = np.minimum(np.hypot(*(v - ref).T), np.hypot(*(v + ref).T))
        whole = dev <= tol
    r = np.hypot(*v.T) / length
    clipped = t.clipped.to_numpy()
    cls = np.select(
        [clipped, whole, r < 0.75, r > 1.25],
        ["clipped", "whole", "fragment", "chain"],
        "wrong_vector",
    )
    bush = np.zeros(len(t), bool)
    if name == "night2":
        for x0, x1, y0, y1 in BUSHES:
            bush |= t.mid_x.between(x0, x1).to_numpy() & t.mid_y.between(y0, y1).to_numpy()
    sat = t.saturated.to_numpy()
    out: dict = {"image": name, "streaks": len(t), "reference_length_px": length}
    for c in ("whole", "fragment", "wrong_vector", "chain", "clipped"):
        m = cls == c
        out[c] = {
            "all": int(m.sum()),
            "outside_bushes_saturated": int((m & ~bush & sat).sum()),
            "outside_bushes_unsaturated": int((m & ~bush & ~sat).sum()),
            "in_bushes": int((m & bush).sum()),
        }
    if ref is not None:
        bad = (cls == "fragment") | (cls == "wrong_vector")
        ends = np.stack([start[bad], end[bad]], axis=1)
        out["joinable_pairs"] = {g: joinable(ends, ref, tol, g) for g in (3, 6, 10)}
    return out


def main() -> int:
    print(json.dumps([classify(n) for n in ("night1", "night2")], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
