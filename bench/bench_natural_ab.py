"""Whole-command A/B of ``blurtrack calibrate`` on natural sessions: a baseline source tree
against this one, on the same sessions, run after run in alternating order (so a shared
machine's load falls on both alike), with wall and CPU of each child
(:func:`bench.natural_common.calibrate`) and whether the two calib.yaml are byte-identical.

    git -C . archive 5c25a55 | tar -x -C /tmp/base     # the baseline tree
    PYTHONPATH=$PWD .venv/bin/python bench/bench_natural_ab.py --base /tmp/base \\
        --sessions /tmp/bench10root --seeds 0-9 --rates 200,1000 --out /tmp/ab

Sessions are ``SESSIONS/r{seed}_{rate}`` as ``bench/bench_natural.py --root DIR --keep``
leaves them. Prints one line per session and the medians; writes ``OUT/ab.json``.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from bench.natural_common import calibrate, parse_seeds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="baseline source tree")
    ap.add_argument("--new", type=Path, default=Path.cwd(), help="tree to compare (default: .)")
    ap.add_argument("--sessions", type=Path, required=True, help="folder of r{seed}_{rate}")
    ap.add_argument("--seeds", default="0-9", help="a list 0,3,5 or a range 2-6")
    ap.add_argument("--rates", default="200,1000")
    ap.add_argument("--out", type=Path, required=True, help="output folder (must not exist)")
    a = ap.parse_args()
    a.out.mkdir(parents=True)
    args = SimpleNamespace(translation="auto", fit=None, axes=None)
    trees = {"base": a.base.resolve(), "new": a.new.resolve()}
    rows: list[dict[str, Any]] = []
    for seed in parse_seeds(a.seeds, count=False):
        for rate in (int(r) for r in a.rates.split(",")):
            name = f"r{seed}_{rate}"
            row: dict[str, Any] = {"session": name}
            for tag in ("base", "new") if len(rows) % 2 == 0 else ("new", "base"):
                os.chdir(trees[tag])  # `python -m blurtrack` runs the tree it starts in
                rec = calibrate(a.sessions / name, a.out / tag / name, args)
                row[tag] = {k: rec.get(k) for k in ("calibrate_wall_s", "calibrate_cpu_s", "rc")}
                row[tag]["load1"] = os.getloadavg()[0]
            yamls = [a.out / t / name / "calib.yaml" for t in ("base", "new")]
            row["identical"] = all(p.is_file() for p in yamls) and filecmp.cmp(
                *yamls, shallow=False
            )
            rows.append(row)
            b, n = row["base"], row["new"]
            print(
                f"{name}: base {b['calibrate_wall_s']:.1f} s ({b['calibrate_cpu_s']:.1f} CPU), "
                f"new {n['calibrate_wall_s']:.1f} s ({n['calibrate_cpu_s']:.1f} CPU), "
                f"identical {row['identical']}, load {n['load1']:.1f}",
                flush=True,
            )
            (a.out / "ab.json").write_text(json.dumps(rows, indent=1))
    for rate in sorted({r["session"].split("_")[1] for r in rows}):
        sel = [r for r in rows if r["session"].endswith("_" + rate)]
        med = {
            t: {
                k: float(np.median([r[t][k] for r in sel]))
                for k in ("calibrate_wall_s", "calibrate_cpu_s")
            }
            for t in ("base", "new")
        }
        ratio = float(
            np.median([r["new"]["calibrate_wall_s"] / r["base"]["calibrate_wall_s"] for r in sel])
        )
        print(
            json.dumps(
                {
                    "rate": rate,
                    "median": med,
                    "median_wall_ratio": ratio,
                    "identical": f"{sum(r['identical'] for r in sel)}/{len(sel)}",
                }
            )
        )


if __name__ == "__main__":
    main()
