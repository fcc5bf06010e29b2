"""Detection on the real light-streak photographs (prints JSON; writes overlay pictures).

No truth exists for these photographs; what is measured (docs/detection.md): how many streaks
are found, how many of them pass the quality flag, and the spread of start-to-end vectors
around the photograph's consensus (every light drew nearly the same curve), orientation-free,
over streaks (neither clipped, crossing nor looped) whose length is within 30 % of their
median length. And, where the photograph's isolated lights form a modal cluster of
components (:mod:`blurtrack.detect.separation.modal`), a count of *whole* streaks that does not
depend on the streaks detected: the reference vector is the median start-to-end vector of those
whole components' skeleton lines, and a streak (not clipped) counts as whole when its vector is
within max(3 px, 25 %) of it, either sign.

Usage: ``python bench/real_streaks.py [--overlay-dir docs/figures] [--images PHOTO ...]``
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

from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.context import prepare_and_segment  # noqa: E402
from blurtrack.detect.overlay import draw_streaks, source_picture  # noqa: E402
from blurtrack.detect.photos import detect_photos  # noqa: E402
from blurtrack.detect.separation.consensus import shape_tolerance  # noqa: E402
from blurtrack.detect.separation.modal import component_references  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real" / "light-streaks"


def whole_reference(img: np.ndarray, sigma_c: float) -> np.ndarray | None:
    """Median start-to-end vector of the photo's whole isolated lights (the modal cluster of
    components, measured along their skeletons), dominant direction; None without one."""
    _, ctx = prepare_and_segment(img, DetectParams())
    out = component_references(ctx, sigma_c, sigma_c)
    if out is None:
        return None
    m, field = out
    v = (m.end_b - m.end_a)[field.use]
    _, vecs = np.linalg.eigh(v.T @ v)
    v = v * np.where(v @ vecs[:, -1] < 0, -1.0, 1.0)[:, None]
    return np.asarray(np.median(v, axis=0))


def measure(path: Path, overlay: Path | None) -> dict:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    got = detect_photos([path])  # what ``blurtrack detect PHOTO`` gives
    fs, table = got.frames[0], got.table
    # The quality flag refuses nearly everything here (these streaks are wider than the
    # frame's typical cross-section: "merged"); measure over streaks that are neither clipped,
    # crossing nor looped.
    ok = table[~(table.clipped | table.crossing | table.looped)]
    v = (ok[["end_x", "end_y"]].to_numpy() - ok[["start_x", "start_y"]].to_numpy()).reshape(-1, 2)
    out = {
        "image": path.name,
        "streaks": len(table),
        "quality_ok": int(table.quality_ok.sum()),
        "source": {k: int(v) for k, v in table.source.value_counts().items()},
        "reason": {k: int(v) for k, v in table.reason.value_counts().items()},
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
    ref = whole_reference(img, fs.sigma_c_px)
    if ref is not None:
        u = table[~table.clipped]
        vu = u[["end_x", "end_y"]].to_numpy() - u[["start_x", "start_y"]].to_numpy()
        dev = np.minimum(np.hypot(*(vu - ref).T), np.hypot(*(vu + ref).T))
        whole = dev <= shape_tolerance(ref[None], DetectParams().quality)[0]
        out.update(
            whole_reference_vector_px=[float(ref[0]), float(ref[1])],
            whole_streaks=int(whole.sum()),
            whole_deviation_median_px=float(np.median(dev[whole])) if whole.any() else None,
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
        src = overlay.with_name(overlay.name.replace("_overlay", "_source"))
        # At 0.6 as the overlay, written as it always was (PNG compression 9: docs/ stays small).
        cv2.imwrite(str(src), source_picture(img, table, 0.6), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        out["source_overlay"] = str(src.relative_to(ROOT)) if src.is_relative_to(ROOT) else str(src)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--overlay-dir", type=Path, default=None)
    ap.add_argument(
        "--images",
        nargs="+",
        type=Path,
        default=[DATA / "night1.jpg", DATA / "night2.jpg"],
        help="photographs to measure (default: the two of ../shared/data/real/light-streaks)",
    )
    args = ap.parse_args()
    res = [
        measure(
            path,
            args.overlay_dir / f"real_{path.stem}_overlay.png" if args.overlay_dir else None,
        )
        for path in args.images
    ]
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
