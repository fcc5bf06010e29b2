"""What each detection stage earns: recall, ok-precision, ok-coverage and time, with and without it.

For each preset and seed (simulated with ``blurtrack simulate``, truth from ``truth.yaml``) the
session is detected once with the full pipeline and once with each stage switched off:

- ``no_separation``: ``DetectParams(separate=False)`` (touching/overlapping streaks are not
  separated with the frame's own templates);
- ``no_gyro_pass``: ``DetectParams(gyro_template=False)`` (no second pass with the gyro's
  predicted curves);
- ``no_session_calibration``: ``DetectParams(gyro_pass=GyroPassParams(session_calibration=False))``
  (the nominal calibration, the template time-shift refinement and the shape search instead
  of the session's fitted calibration error);
- ``no_artefact_filter``: ``DetectParams(artefact_ratio=0)`` (ringing/blooming components kept);
- ``no_clip_choice``: ``DetectParams(gyro_pass=GyroPassParams(clip_choice=False))`` (the
  template pass measures each placement once, on the neighbours' templates subtracted as
  they are, not also on that difference clipped at zero);
- ``no_shift_refine``: ``detect_session(refine_timeshift=False)`` (the session's time offset
  is not re-fitted from the streaks before orientation);
- ``no_gyro``: ``detect_session(gyro="off")`` (orientation and every gyro stage off).

Measures (``bench_detect``'s definitions): recall of true inside streaks, ok-precision (quality_ok
detections with both ends within 2 px of a true streak's), ok-coverage (true inside streaks
matched by a quality_ok detection), and the CPU seconds of ``detect_session`` on one worker
(``time.process_time``: what the stage costs, less sensitive to other load than wall time),
beside the CPU seconds of the plain baseline (``cv2.imread`` + ``GaussianBlur`` + ``threshold`` +
``connectedComponentsWithStats``) over the same image files. Each run's line goes to stderr and
to ``--partial`` as it finishes; the JSON on stdout pools the seeds per preset and variant.

Usage: ``python bench/detect_stages.py --presets dense hard --seeds 3 4 --frames 8``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_detect import baseline_files, evaluate, simulate, trust  # noqa: E402

from blurtrack.detect import DetectParams  # noqa: E402
from blurtrack.detect.params import GyroPassParams  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402

#: Variant name -> (parameters, detect_session keyword arguments).
VARIANTS: dict[str, tuple[DetectParams, dict[str, Any]]] = {
    "full": (DetectParams(), {}),
    "no_separation": (DetectParams(separate=False), {}),
    "no_gyro_pass": (DetectParams(gyro_template=False), {}),
    "no_session_calibration": (
        DetectParams(gyro_pass=GyroPassParams(session_calibration=False)),
        {},
    ),
    "no_artefact_filter": (DetectParams(artefact_ratio=0.0), {}),
    "no_clip_choice": (DetectParams(gyro_pass=GyroPassParams(clip_choice=False)), {}),
    "no_shift_refine": (DetectParams(), {"refine_timeshift": False}),
    "no_gyro": (DetectParams(), {"gyro": "off"}),
}


def baseline_cpu_s(session: Any) -> float:
    """CPU seconds of :func:`bench_detect.baseline_files` over the session's frames."""
    t0 = time.process_time()
    baseline_files([session.image_path(i) for i in range(len(session.frames))])
    return time.process_time() - t0


def run_variant(folder: Path, name: str) -> dict[str, Any]:
    params, kwargs = VARIANTS[name]
    session = load_session(folder)
    t0 = time.process_time()
    res = detect_session(session, params, workers=1, **kwargs)
    cpu = time.process_time() - t0
    truth = session.truth or {"frames": []}
    ev = evaluate(res.table, truth)
    tr = trust(res.table, truth)
    c = ev["_counts"]
    return {
        "variant": name,
        "recall_inside": ev["recall_inside"],
        "ok_precision": tr["ok_precision"],
        "ok_coverage": tr["ok_coverage"],
        "cpu_s": cpu,
        "baseline_cpu_s": baseline_cpu_s(session),
        "_recall_counts": (int(c[2]), int(c[3])),
        "_trust_counts": tuple(int(v) for v in tr["_trust_counts"]),
    }


def pooled(runs: list[dict[str, Any]]) -> dict[str, Any]:
    r = np.sum([x["_recall_counts"] for x in runs], axis=0)
    t = np.sum([x["_trust_counts"] for x in runs], axis=0)
    cpu = float(sum(x["cpu_s"] for x in runs))
    base = float(sum(x["baseline_cpu_s"] for x in runs))
    return {
        "recall_inside": float(r[0] / max(r[1], 1)),
        "ok_precision": float(t[0] / max(t[1], 1)),
        "ok_coverage": float(t[2] / max(t[3], 1)),
        "ok_detections": int(t[1]),
        "cpu_s": cpu,
        "cpu_ratio_to_baseline": cpu / max(base, 1e-9),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["dense", "hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[3, 4])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--work", type=Path, default=ROOT / "bench_out" / "detect")
    ap.add_argument("--partial", type=Path, default=None, help="append each run's JSON line")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = []
    for preset in args.presets:
        for seed in args.seeds:
            folder = simulate(args.work, preset, args.frames, seed)
            for name in args.variants:
                r = {"preset": preset, "seed": seed, **run_variant(folder, name)}
                runs.append(r)
                line = json.dumps({k: v for k, v in r.items() if not k.startswith("_")})
                print(line, file=sys.stderr)
                if args.partial is not None:
                    with args.partial.open("a") as fh:
                        fh.write(line + "\n")
    out: dict[str, Any] = {"frames": args.frames, "seeds": args.seeds, "presets": {}}
    for preset in args.presets:
        per = {
            name: pooled([r for r in runs if r["preset"] == preset and r["variant"] == name])
            for name in args.variants
        }
        full = per.get("full")
        if full is not None:
            for p in per.values():
                p["delta_vs_full"] = {
                    k: p[k] - full[k] for k in ("recall_inside", "ok_precision", "ok_coverage")
                }
                p["cpu_share_of_full"] = p["cpu_s"] / max(full["cpu_s"], 1e-9)
        out["presets"][preset] = per
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
