"""CPU seconds of ``detect_session`` in this code tree against another, interleaved (issue 45).

For each session, ``detect_session(load_session(S), workers=1)`` runs in a fresh subprocess of
each tree in turn (the order alternating every repetition, so that a change in the machine's
other load falls on both), timed by ``time.process_time`` (less sensitive to other load than
wall time): the whole call and, inside it, the gyro-template pass's frame refinement
(``refine_frames``; the time-shift refinement by templates is not in it). The JSON gives every
run and, per tree, the medians, the pass's share and the ratios before / after.

Usage: ``git -C MAIN archive HEAD | tar -x -C /tmp/old`` then
``python bench/detect_cpu_ab.py --before /tmp/old --repeat 3 SESSION...``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from json_out import emit  # noqa: E402

#: Run in the subprocess (its tree first on ``sys.path``): one timed ``detect_session``.
_CHILD = """
import json, sys, time
from blurtrack.detect.session import pipeline as sess
spent = [0.0]
refine = sess.refine_frames
def timed(*a, **k):
    t0 = time.process_time()
    try:
        return refine(*a, **k)
    finally:
        spent[0] += time.process_time() - t0
sess.refine_frames = timed
from blurtrack.io.session import load_session
s = load_session(sys.argv[1])
t0 = time.process_time()
sess.detect_session(s, workers=1)
print(json.dumps({"cpu_s": time.process_time() - t0, "gyro_pass_cpu_s": spent[0]}))
"""


def one_run(tree: Path, session: Path) -> dict[str, float]:
    """CPU seconds of one ``detect_session`` of ``session`` with the code of ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(session)],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    got: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return {k: round(v, 3) for k, v in got.items()}


def summarise(runs: list[dict[str, float]]) -> dict[str, Any]:
    """Medians of a tree's runs on one session and the gyro pass's share of the total."""
    cpu = statistics.median(r["cpu_s"] for r in runs)
    gyro = statistics.median(r["gyro_pass_cpu_s"] for r in runs)
    return {
        "cpu_s_median": round(cpu, 2),
        "gyro_pass_cpu_s_median": round(gyro, 2),
        "gyro_share": round(gyro / cpu, 3) if cpu > 0 else None,
        "runs": runs,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sessions", nargs="+", type=Path)
    ap.add_argument("--before", type=Path, required=True, help="the other code tree")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    trees = {"before": args.before.resolve(), "after": ROOT}
    runs: dict[str, dict[str, list[dict[str, float]]]] = {
        str(s): {t: [] for t in trees} for s in args.sessions
    }
    for r in range(args.repeat):
        order = list(trees.items()) if r % 2 == 0 else list(trees.items())[::-1]
        for s in args.sessions:
            for name, tree in order:
                runs[str(s)][name].append(one_run(tree, s))
                print(s, name, runs[str(s)][name][-1], file=sys.stderr, flush=True)
    result: dict[str, Any] = {}
    for s, per_tree in runs.items():
        b, a = summarise(per_tree["before"]), summarise(per_tree["after"])
        result[s] = {
            "before": b,
            "after": a,
            "ratio_total": round(b["cpu_s_median"] / a["cpu_s_median"], 2),
            "ratio_gyro_pass": round(
                b["gyro_pass_cpu_s_median"] / max(a["gyro_pass_cpu_s_median"], 1e-9), 2
            ),
        }
    return emit(result, args.out)


if __name__ == "__main__":
    raise SystemExit(main())
