"""Detection on the real light-streak photographs (prints JSON; writes overlay pictures).

No truth exists for these photographs; what is measured (docs/detection.md): how many streaks
are found, how many of them pass the quality flag, and the spread of start-to-end vectors
around the photograph's consensus (every light drew nearly the same curve), orientation-free,
over streaks (neither clipped, crossing nor looped) whose length is within 30 % of their
median length.

Usage: ``python bench/real_streaks.py [--overlay-dir docs/figures]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blurtrack.detect import detect_frame  # noqa: E402
from blurtrack.detect.orientation import combine  # noqa: E402
from blurtrack.detect.overlay import draw_streaks  # noqa: E402
from blurtrack.detect.table import build_table, frame_rows  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real" / "light-streaks"


def measure(path: Path, overlay: Path | None) -> dict:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    fs = detect_frame(img)
    table = build_table([frame_rows(0, 0, fs, combine(np.zeros((len(fs), 3))))])
    # The quality flag refuses nearly everything here (these streaks are wider than the
    # frame's typical cross-section: "merged"); measure over streaks that are neither clipped,
    # crossing nor looped.
    ok = table[~(table.clipped | table.crossing | table.looped)]
    v = (ok[["end_x", "end_y"]].to_numpy() - ok[["start_x", "start_y"]].to_numpy()).reshape(-1, 2)
    out = {
        "image": path.name,
        "streaks": len(table),
        "quality_ok": int(table.quality_ok.sum()),
        "measured": len(ok),
        "flags": {c: int(table[c].sum()) for c in ("clipped", "saturated", "merged", "looped")},
    }
    if len(ok) >= 3:
        L = ok["length_px"].to_numpy()
        similar = np.abs(L - np.median(L)) <= 0.3 * np.median(L)
        w = v[similar]
        _, vecs = np.linalg.eigh(w.T @ w)
        w = w * np.where(w @ vecs[:, -1] < 0, -1.0, 1.0)[:, None]
        c = np.median(w, axis=0)
        dev = np.hypot(*(w - c).T)
        out.update(
            similar_length_streaks=int(similar.sum()),
            consensus_vector_px=[float(c[0]), float(c[1])],
            median_length_px=float(np.median(L)),
            vector_deviation_median_px=float(np.median(dev)),
        )
    if overlay is not None:
        pic = draw_streaks(img, table, scale=1)
        # Half-size pictures keep docs/ small (< 500 kB each).
        pic = cv2.resize(pic, None, fx=0.6, fy=0.6, interpolation=cv2.INTER_AREA)
        overlay.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(overlay), pic, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        out["overlay"] = (
            str(overlay.relative_to(ROOT)) if overlay.is_relative_to(ROOT) else str(overlay)
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--overlay-dir", type=Path, default=None)
    args = ap.parse_args()
    res = [
        measure(
            DATA / f"{n}.jpg",
            args.overlay_dir / f"real_{n}_overlay.png" if args.overlay_dir else None,
        )
        for n in ("night1", "night2")
    ]
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
