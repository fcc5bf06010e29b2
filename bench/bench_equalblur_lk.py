"""The equal-blur Lucas–Kanade (``blurtrack.features.equalblur.lucas_kanade``) against the
same function of a ``--before`` tree, on the same synthetic patches, in the same run.

``--tracks`` template/target pairs are cut from a smoothed noise image, each target shifted by
up to 2 px; a third of the targets come from elsewhere, so they never converge and run every
iteration, as unmatched tracks of a real session do. Prints JSON: both translations and flags
equal bit for bit, CPU seconds (``time.process_time``) of each implementation over
``--repeat`` interleaved runs (median) and their ratio.

    git archive 3a25289 | tar -x -C /tmp/lk_before
    .venv/bin/python bench/bench_equalblur_lk.py --before /tmp/lk_before --tracks 12000
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import time
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from blurtrack.features import equalblur


def _load_before(tree: Path) -> ModuleType:
    path = tree / "blurtrack" / "features" / "equalblur.py"
    if not path.is_file():
        raise SystemExit(f"--before {tree}: no blurtrack/features/equalblur.py there")
    spec = importlib.util.spec_from_file_location("equalblur_before", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"--before {tree}: cannot load {path}")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _patches(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = equalblur.WINDOW_PX
    size = 2 * (w // 2 + equalblur.MARGIN_PX + 1) + 1
    img = cv2.GaussianBlur(rng.random((900, 1400)).astype(np.float32) * 255, (0, 0), 1.5)
    c = np.column_stack([rng.uniform(40, 1360, n), rng.uniform(40, 860, n)])
    shift = rng.uniform(-2, 2, (n, 2))
    far = rng.random(n) < 1 / 3
    src = np.where(far[:, None], np.column_stack([rng.uniform(40, 1360, n), c[:, 1]]), c + shift)
    tpl = np.stack([cv2.getRectSubPix(img, (w + 2, w + 2), (p[0], p[1])) for p in c])
    tgt = np.stack([cv2.getRectSubPix(img, (size, size), (p[0], p[1])) for p in src])
    return tpl, tgt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="tree holding the old package")
    ap.add_argument("--tracks", type=int, default=12000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    before = _load_before(a.before)
    tpl, tgt = _patches(a.tracks, a.seed)
    cpu: dict[str, list[float]] = {"before": [], "after": []}
    res = {}
    for _ in range(a.repeat):
        for name, fn in (("before", before.lucas_kanade), ("after", equalblur.lucas_kanade)):
            t0 = time.process_time()
            res[name] = fn(tpl, tgt)
            cpu[name].append(time.process_time() - t0)
    med = {k: statistics.median(v) for k, v in cpu.items()}
    out = {
        "tracks": a.tracks,
        "converged": float(np.mean(res["after"][1])),
        "identical": bool(
            np.array_equal(res["before"][0], res["after"][0])
            and np.array_equal(res["before"][1], res["after"][1])
        ),
        "cpu_s": cpu,
        "cpu_median_s": med,
        "ratio_after_before": med["after"] / med["before"],
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
