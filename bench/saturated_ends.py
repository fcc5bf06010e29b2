"""Where the detector places the ends of saturated streaks, against their analytic truth
(prints JSON).

Straight streaks of 50 px (a 4 x 6 grid in a 700 x 400 frame, directions within +-0.4 rad of
the rows) rendered exactly (:func:`blurtrack.testing.streak_frames.render_streaks`, PSF sigma
1.5 px, background 0.03, noise 0.004 of full scale, 8 bits), each at a plateau peak of
``peak`` times the saturation, at a constant speed or slowing down (``accel``: the speed falls
from ``1 + accel`` to ``1 - accel`` times the mean, :func:`~blurtrack.testing.streak_frames.line`);
:func:`blurtrack.detect.detect_frame` with the default parameters. Per case: the median and
largest outward error along the streak (px; positive: beyond the true end) of the start and
of the end.

Usage: ``python bench/saturated_ends.py [--peaks 0.2 1 4 10 27 80 270] [--accels 0 0.8]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from json_out import emit  # noqa: E402

from blurtrack.detect import DetectParams, detect_frame  # noqa: E402
from blurtrack.testing.streak_frames import outward_errors, saturated_grid  # noqa: E402

SIGMA_PX = 1.5
LENGTH_PX = 50.0


def saturated_case(peak: float, accel: float, seed: int = 3) -> dict[str, Any]:
    """The start's and the end's outward errors (px) of the grid's streaks at ``peak`` times
    the saturation."""
    image, truth = saturated_grid(peak, accel, SIGMA_PX, LENGTH_PX, seed)
    fs = detect_frame(image, DetectParams())
    s, e = outward_errors(fs.end_a, fs.end_b, truth)
    return {
        "peak_over_saturation": peak,
        "accel": accel,
        "start_out_median_px": round(float(np.median(s)), 3),
        "end_out_median_px": round(float(np.median(e)), 3),
        "largest_abs_px": round(float(max(np.abs(s).max(), np.abs(e).max())), 3),
        "saturated_pixels": round(float(np.mean(image == 255)), 4),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peaks", nargs="+", type=float, default=[0.2, 1, 4, 10, 27, 80, 270])
    ap.add_argument("--accels", nargs="+", type=float, default=[0.0, 0.8])
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args()
    runs = [saturated_case(p, a) for a in args.accels for p in args.peaks]
    return emit({"runs": runs}, args.out)


if __name__ == "__main__":
    sys.exit(main())
