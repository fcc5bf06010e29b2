"""``quality_ok`` on the real recordings' natural frames (prints JSON).

The frames of the three real recordings in ``../shared/data/real`` (a hand-held DeepGyro burst,
a MARS-logger phone video, a phone video from a driving car) hold no laser dots: lamps, lit
windows, headlights, screens, sky and glare. None of them was used to develop the detector.
A ``quality_ok`` streak there is a confident detection on something that is not a point light
drawn by the shake (or, rarely, a real small lamp): the count should be 0. Per recording: the
frames, detections, ``quality_ok``, ``source`` and ``reason`` counts.

Usage: ``python bench/natural_trust.py [--every K]`` (every K-th frame of each recording;
default 1: all).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
from natural_negatives import frame_table  # bench/ is on the path (the script's folder)

ROOT = Path(__file__).resolve().parents[1]

DATA = ROOT.parent / "shared" / "data" / "real"
#: Each recording's frames, relative to :data:`DATA`.
RECORDINGS = {
    "deepgyro-shield": "deepgyro-shield/images",
    "marslogger-phone": "marslogger-phone/video_frames",
    "phone-video-412hz": "phone-video-412hz/frames",
}


def image(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img


def recording(name: str, every: int) -> dict:
    files = sorted((DATA / RECORDINGS[name]).glob("*.jpg"))[::every]
    source: Counter[str] = Counter()
    reason: Counter[str] = Counter()
    n = ok = 0
    for f in files:
        t = frame_table(image(f))
        n += len(t)
        ok += int(t.quality_ok.sum())
        source.update(t.source.tolist())
        reason.update(t.reason.tolist())
    return {
        "recording": name,
        "frames": len(files),
        "detections": n,
        "quality_ok": ok,
        "source": dict(source),
        "reason": dict(reason),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=int, default=1)
    a = ap.parse_args(argv)
    if not DATA.is_dir():
        raise SystemExit(f"real data not found at {DATA}")
    print(json.dumps([recording(name, max(a.every, 1)) for name in RECORDINGS], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
