"""Detection on natural photographs that hold no point-light streak (prints JSON).

The BSDS500 photographs in ``../shared/data/backgrounds/bsds500`` are daylight scenes (sky,
water, walls, foliage, faces): every streak the detector finds there is on an extended source,
so every ``quality_ok`` detection is a false one. Measured per photo (each as stored, and
dimmed to a quarter with the same shot noise a dark frame has, which lifts fewer regions over
the threshold and leaves small bright ones: highlights, lamps, reflections): streaks found,
``quality_ok``, and the ``source`` split; pooled: photos with any ``quality_ok``, the total and
the share of streaks called ``point``.

Usage: ``python bench/natural_negatives.py --split test --count 100``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blurtrack.detect import detect_frame  # noqa: E402
from blurtrack.detect.orientation import combine  # noqa: E402
from blurtrack.detect.table import build_table, frame_rows  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "backgrounds" / "bsds500"


def dimmed(img: np.ndarray, seed: int) -> np.ndarray:
    """``img`` at a quarter of its light, with the shot and read noise of a dark 8-bit frame."""
    rng = np.random.default_rng(seed)
    x = img.astype(np.float64) * 0.25
    x = x + rng.normal(0.0, 1.0, x.shape) * np.sqrt(0.5 * x + 1.0)
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def frame_table(img: np.ndarray):  # type: ignore[no-untyped-def]
    """The streak table of one image, image evidence only (no gyro)."""
    fs = detect_frame(img)
    return build_table([frame_rows(0, 0, fs, combine(np.zeros((len(fs), 3))))])


def measure(img: np.ndarray) -> dict[str, Any]:
    table = frame_table(img)
    return {
        "streaks": len(table),
        "quality_ok": int(table.quality_ok.sum()) if len(table) else 0,
        "source": {k: int(v) for k, v in table.source.value_counts().items()} if len(table) else {},
    }


def pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    streaks = sum(r["streaks"] for r in rows)
    point = sum(r["source"].get("point", 0) for r in rows)
    return {
        "photos": len(rows),
        "photos_with_quality_ok": sum(1 for r in rows if r["quality_ok"]),
        "quality_ok": sum(r["quality_ok"] for r in rows),
        "streaks": streaks,
        "point_share": point / max(streaks, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--count", type=int, default=100)
    args = ap.parse_args()
    files = sorted((DATA / args.split).glob("*.jpg"))[: args.count]
    if not files:
        print(f"no photographs under {DATA / args.split}", file=sys.stderr)
        return 2
    out: dict[str, list[dict[str, Any]]] = {"as_stored": [], "dimmed": []}
    for k, f in enumerate(files):
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            print(f"cannot decode {f.name}", file=sys.stderr)
            return 2
        for name, im in (("as_stored", img), ("dimmed", dimmed(img, k))):
            row = {"image": f.name, **measure(im)}
            out[name].append(row)
            if row["quality_ok"]:
                print(f"{name} {f.name}: {row}", file=sys.stderr)
    result = {name: {"pooled": pooled(rows), "photos": rows} for name, rows in out.items()}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
