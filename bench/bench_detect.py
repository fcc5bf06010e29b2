"""Benchmark of streak detection against simulator truth (prints JSON).

For each preset and seed: simulate a session with ``blurtrack simulate`` (or use ``--session``),
run ``detect_session`` and compare with ``truth.yaml``:

- endpoint error after start/end resolution (median, 95th percentile) on matched streaks that
  lie fully inside the frame;
- start/end resolved correctly, for true streaks longer than 5 px;
- recall (true inside streaks found) and precision (unclipped detections that are real);
- trust (issue 45): ok-precision, the share of ``quality_ok`` detections whose both ends lie
  within 2 px of one true streak's (either orientation), and ok-coverage, the share of true
  inside streaks such a detection matches; where the preset's colour sensor has lateral
  colour (``chromatic_px``, docs/simulator.md), also ``ok_precision_light``, the same against
  the light's own geometry (:func:`light_magnification`);
- speed: frames/s of the per-frame detection on one core, and the same frames through a plain
  ``cv2.GaussianBlur`` + ``cv2.connectedComponentsWithStats`` pass in the same run (ratio);
- whole command (``--command``): the wall time of the command a user runs, ``blurtrack detect
  SESSION`` as a subprocess (start-up, decoding, detection, orientation, time-shift scan,
  writing), with ``--workers 1`` and with the default workers (all cores), against the
  single-core baseline ``cv2.imread`` + ``GaussianBlur`` + ``threshold`` +
  ``connectedComponentsWithStats`` over the same image files, interleaved in the same run;
  wall ratios (what a user waits: the workers use every core, the baseline one) and CPU
  ratios (core-seconds). ``--before ROOT`` times another code tree the same way.

Usage: ``python bench/bench_detect.py --presets clean realistic hard --seeds 1 2 3 --frames 20``
(a preset may be a YAML file, ``--presets configs/sim/hard_long_exposure.yaml``);
``python bench/bench_detect.py --command --presets dense hard --seeds 1 --frames 100``;
``git -C MAIN archive HEAD | tar -x -C /tmp/old`` then ``... --command --before /tmp/old``
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blurtrack.detect import DetectParams, detect_frame  # noqa: E402
from blurtrack.detect.image import LUMA_BGR  # noqa: E402
from blurtrack.detect.session.pipeline import detect_session  # noqa: E402
from blurtrack.io.session import load_session  # noqa: E402

MATCH_GATE_PX = 4.0  # mean endpoint distance (either orientation) for a match
#: Issue 45's trust gate: a quality_ok detection is right when BOTH its ends lie within this
#: distance of one true streak's ends (either orientation).
TRUST_GATE_PX = 2.0


def end_distances(
    s: np.ndarray, e: np.ndarray, S: np.ndarray, E: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(n, m)`` px each: the farther of the two ends of detections ``s, e (n, 2)`` from those
    of true streaks ``S, E (m, 2)``, the same way round and swapped."""
    same = np.maximum(
        np.linalg.norm(s[:, None] - S[None], axis=2),
        np.linalg.norm(e[:, None] - E[None], axis=2),
    )
    swap = np.maximum(
        np.linalg.norm(s[:, None] - E[None], axis=2),
        np.linalg.norm(e[:, None] - S[None], axis=2),
    )
    return same, swap


def worse_end_distance(s: np.ndarray, e: np.ndarray, S: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``(n, m)`` px: the farther of the two ends of detections ``s, e (n, 2)`` from those of
    true streaks ``S, E (m, 2)``, in whichever orientation fits better."""
    return np.minimum(*end_distances(s, e, S, E))


def light_magnification(truth: dict[str, Any]) -> float | None:
    """Where the simulated colour sensor has lateral colour (``chromatic_px`` > 0: the red
    image magnified and the blue one shrunk about the centre by that much at the corner,
    rigs/sim/optics.py), the magnification about the centre of the light that detection
    measures (the luma of the dots' one-colour light, each channel weighted by its luma weight
    times the sensor's ``colour_response``): ``1 + s (w_r - w_b) / (w_r + w_g + w_b)``,
    ``s = chromatic_px / r_corner``. The truth is the lens's geometry without it; a red
    laser's light lies magnified (``phone``: by 0.71 px at the corner), which a calibration
    from red streaks takes into its focal length. None without lateral colour."""
    preset = (truth.get("simulator") or {}).get("preset") or {}
    chrom = float(preset.get("chromatic_px") or 0.0)
    response = preset.get("colour_response")
    if chrom <= 0.0 or not response:
        return None
    r, g, b = (float(v) for v in response)
    w_b, w_g, w_r = (w * c for w, c in zip(LUMA_BGR, (b, g, r), strict=True))
    r_corner = float(np.hypot((preset["width"] - 1) / 2, (preset["height"] - 1) / 2))
    return 1.0 + chrom / r_corner * (w_r - w_b) / (w_r + w_g + w_b)


def trust(table: pd.DataFrame, truth: dict[str, Any]) -> dict[str, Any]:
    """ok-precision (share of ``quality_ok`` detections with both ends within
    :data:`TRUST_GATE_PX` of one true streak's, either orientation), ok-coverage (share of
    true inside streaks that such a detection matches) and the counts behind them."""
    ok = table["quality_ok"].to_numpy(bool) if "quality_ok" in table.columns else None
    n_ok = n_right = n_inside = n_covered = n_right_light = 0
    mag = light_magnification(truth)
    preset = (truth.get("simulator") or {}).get("preset") or {}
    centre = np.array([(preset.get("width", 0) - 1) / 2, (preset.get("height", 0) - 1) / 2])
    for fr in truth["frames"]:
        S, E, inside, _ = truth_arrays(fr)
        n_inside += int(inside.sum())
        sel = (table["frame"] == fr["index"]).to_numpy().copy()
        if ok is not None:
            sel &= ok
        d = table[sel]
        n_ok += len(d)
        if len(d) == 0 or len(S) == 0:
            continue
        s = d[["start_x", "start_y"]].to_numpy(float)
        e = d[["end_x", "end_y"]].to_numpy(float)
        hit = worse_end_distance(s, e, S, E) <= TRUST_GATE_PX
        n_right += int(hit.any(axis=1).sum())
        n_covered += int((hit.any(axis=0) & inside).sum())
        if mag is not None:
            Sl, El = centre + (S - centre) * mag, centre + (E - centre) * mag
            n_right_light += int((worse_end_distance(s, e, Sl, El) <= TRUST_GATE_PX).any(1).sum())
    out: dict[str, Any] = {
        "ok_precision": n_right / max(n_ok, 1),
        "ok_coverage": n_covered / max(n_inside, 1),
        "ok_detections": n_ok,
        "ok_wrong": n_ok - n_right,
        "_trust_counts": (n_right, n_ok, n_covered, n_inside),
    }
    if mag is not None:
        out["ok_precision_light"] = n_right_light / max(n_ok, 1)
        out["ok_wrong_light"] = n_ok - n_right_light
    return out


def simulate(out: Path, preset: str, frames: int, seed: int) -> Path:
    """The session of ``preset`` (a built-in name, or a preset YAML file: ``blurtrack simulate
    --preset-file``, e.g. ``configs/sim/hard_long_exposure.yaml``), ``frames`` frames, ``seed``,
    simulated into ``out`` once (a file's session is named for its stem and a hash of its
    text, so that an edited file is simulated anew)."""
    if preset.endswith((".yaml", ".yml")):
        path = Path(preset).resolve()
        digest = hashlib.sha1(path.read_bytes()).hexdigest()[:8]
        folder = out / f"{path.stem}-{digest}-s{seed}-f{frames}"
        which = ["--preset-file", str(path)]
    else:
        folder = out / f"{preset}-s{seed}-f{frames}"
        which = ["--preset", preset]
    if not (folder / "truth.yaml").is_file():
        cmd = [sys.executable, "-m", "blurtrack", "simulate", str(folder), *which]
        cmd += ["--frames", str(frames), "--seed", str(seed)]
        subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True)
    return folder


def truth_arrays(frame: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    st = frame.get("streaks") or []
    S = np.array([s["start"] for s in st], float).reshape(-1, 2)
    E = np.array([s["end"] for s in st], float).reshape(-1, 2)
    inside = np.array([bool(s.get("inside", True)) for s in st], bool)
    length = np.array(
        [float(s.get("length_px", np.linalg.norm(np.subtract(s["end"], s["start"])))) for s in st]
    )
    return S, E, inside, length


def match(
    s: np.ndarray, e: np.ndarray, S: np.ndarray, E: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Detections ``s, e`` ``(n, 2)`` matched to true streaks ``S, E`` ``(m, 2)``: the
    ``(n, m)`` orientation-free mean endpoint distance, the Hungarian assignment's rows and
    columns within :data:`MATCH_GATE_PX`, and ``(n, m)`` whether start and end are the
    right way round."""
    same = (
        np.linalg.norm(s[:, None] - S[None], axis=2) + np.linalg.norm(e[:, None] - E[None], axis=2)
    ) / 2
    swap = (
        np.linalg.norm(s[:, None] - E[None], axis=2) + np.linalg.norm(e[:, None] - S[None], axis=2)
    ) / 2
    cost = np.minimum(same, swap)
    rows, cols = linear_sum_assignment(np.where(cost < MATCH_GATE_PX, cost, 1e6))
    ok = cost[rows, cols] < MATCH_GATE_PX
    return cost, rows[ok], cols[ok], same <= swap


def evaluate(table, truth: dict[str, Any]) -> dict[str, Any]:
    errors: list[float] = []
    mid_errors: list[float] = []
    n_oriented = n_long = 0
    n_inside = n_found = 0
    n_det_unclipped = n_det_real = 0
    for fr in truth["frames"]:
        S, E, inside, length = truth_arrays(fr)
        d = table[table["frame"] == fr["index"]]
        s = d[["start_x", "start_y"]].to_numpy(float)
        e = d[["end_x", "end_y"]].to_numpy(float)
        m = d[["mid_x", "mid_y"]].to_numpy(float)
        M = np.array(
            [st.get("mid", [np.nan, np.nan]) for st in fr.get("streaks") or []], float
        ).reshape(-1, 2)
        clipped = d["clipped"].to_numpy(bool)
        saturated = d["saturated"].to_numpy(bool)
        n_inside += int(inside.sum())
        n_det_unclipped += int((~clipped).sum())
        if len(d) == 0 or len(S) == 0:
            continue
        _, rows, cols, oriented = match(s, e, S, E)
        n_found += int(inside[cols].sum())
        n_det_real += int((~clipped[rows]).sum())
        for r, c in zip(rows, cols, strict=True):
            if not inside[c]:
                continue
            errors += [float(np.linalg.norm(s[r] - S[c])), float(np.linalg.norm(e[r] - E[c]))]
            if np.all(np.isfinite(M[c])) and not saturated[r]:
                mid_errors.append(float(np.linalg.norm(m[r] - M[c])))
            if length[c] > 5.0:
                n_long += 1
                n_oriented += int(oriented[r, c])
    err = np.array(errors) if errors else np.array([np.nan])
    mid = np.array(mid_errors) if mid_errors else np.array([np.nan])
    return {
        # Time midpoints (what calibration's inter-frame tracks use), unsaturated streaks.
        "mid_error_median_px": float(np.median(mid)),
        "mid_error_p95_px": float(np.percentile(mid, 95)),
        "endpoint_error_median_px": float(np.median(err)),
        "endpoint_error_p95_px": float(np.percentile(err, 95)),
        "orientation_correct": n_oriented / max(n_long, 1),
        "orientation_streaks_over_5px": n_long,
        "recall_inside": n_found / max(n_inside, 1),
        "precision_unclipped": n_det_real / max(n_det_unclipped, 1),
        "true_inside_streaks": n_inside,
        "_errors": errors,
        "_counts": (n_oriented, n_long, n_found, n_inside, n_det_real, n_det_unclipped),
    }


def _gray(img: np.ndarray) -> np.ndarray:
    """Colour frames (BGR) to one channel for the baseline."""
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def speed(frames: list[np.ndarray], params: DetectParams, repeat: int) -> dict[str, float]:
    cv2.setNumThreads(1)

    def base(img: np.ndarray) -> None:
        g = cv2.GaussianBlur(_gray(img), (0, 0), 1.0)
        thr = float(np.median(g[::8, ::8])) + 10.0 * (256 if img.dtype == np.uint16 else 1)
        cv2.connectedComponentsWithStats((g > thr).view(np.uint8), connectivity=8)

    t_det: list[float] = []
    t_base: list[float] = []
    for _ in range(repeat):  # interleaved, so that machine load affects both alike
        for img in frames:
            t0 = time.perf_counter()
            base(img)
            t1 = time.perf_counter()
            detect_frame(img, params)
            t2 = time.perf_counter()
            t_base.append(t1 - t0)
            t_det.append(t2 - t1)
    det, bas = float(np.median(t_det)), float(np.median(t_base))
    return {
        "detect_fps": 1.0 / det,
        "baseline_fps": 1.0 / bas,
        "time_ratio": det / bas,
        "detect_ms_median": det * 1e3,
        "baseline_ms_median": bas * 1e3,
    }


def baseline_files(paths: list[Path]) -> None:
    """The baseline over image files: decode, smooth, threshold, label (one core)."""
    for path in paths:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        g = cv2.GaussianBlur(_gray(img), (0, 0), 1.0)
        thr = float(np.median(g[::8, ::8])) + 10.0 * (256 if img.dtype == np.uint16 else 1)
        _, mask = cv2.threshold(g, thr, 255, cv2.THRESH_BINARY)
        cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)


def command_speed(
    folder: Path,
    repeat: int,
    work: Path,
    before: Path | None = None,
    params: Path | None = None,
    gyro: str = "auto",
) -> dict[str, Any]:
    """Wall and CPU time of ``blurtrack detect`` (subprocess) against the file baseline,
    interleaved; with ``before``, also that of the code tree at ``before`` (another checkout,
    run with the same interpreter), so that both are timed under the same load. ``params``
    (a YAML file) and ``gyro`` go to every command as ``--params`` and ``--gyro``."""
    cv2.setNumThreads(1)
    session = load_session(folder)
    paths = [session.image_path(i) for i in range(len(session.frames))]
    out = work / f"{folder.name}.bench.parquet"
    variants: dict[str, tuple[Path, list[str]]] = {
        "workers_1": (ROOT, ["--workers", "1"]),
        "workers_default": (ROOT, []),
    }
    if before is not None:
        variants["before_workers_1"] = (before, ["--workers", "1"])
        variants["before_workers_default"] = (before, [])
    times: dict[str, list[float]] = {"baseline": [], **{k: [] for k in variants}}
    cpu: dict[str, list[float]] = {k: [] for k in times}
    for _ in range(repeat):  # interleaved, so that machine load affects all alike
        t0, c0 = time.perf_counter(), time.process_time()
        baseline_files(paths)
        times["baseline"].append(time.perf_counter() - t0)
        cpu["baseline"].append(time.process_time() - c0)
        for name, (root, extra) in variants.items():
            cmd = [
                sys.executable,
                "-m",
                "blurtrack",
                "detect",
                str(folder),
                "--out",
                str(out),
                "--force",
                "--gyro",
                gyro,
            ]
            if params is not None:
                cmd += ["--params", str(params.resolve())]
            # As installed: bytecode cached (pip compiles on install). A machine that sets
            # PYTHONDONTWRITEBYTECODE (these do) would compile every module on every run,
            # ~0.15 s of the command that no user pays; the first repeat writes the caches.
            env = dict(os.environ, PYTHONPATH=str(root))
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run(cmd + extra, check=True, cwd=root, capture_output=True, env=env)
            times[name].append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu[name].append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
    med = {k: float(np.median(v)) for k, v in times.items()}
    med_cpu = {k: float(np.median(v)) for k, v in cpu.items()}
    n = len(paths)
    res: dict[str, Any] = {
        "frames": n,
        "cores": os.cpu_count(),
        "load_1min": os.getloadavg()[0],
        "gyro": gyro,
        "params": None if params is None else str(params),
    }
    for k, v in med.items():
        res[f"{k}_s"] = v
        res[f"{k}_fps"] = n / v
        res[f"{k}_cpu_s"] = med_cpu[k]
    for k in variants:
        # Wall ratio (what a user waits) and CPU ratio (core-seconds; less sensitive to load).
        res[f"ratio_{k}"] = med[k] / med["baseline"]
        res[f"cpu_ratio_{k}"] = med_cpu[k] / med_cpu["baseline"]
    res["streaks_per_frame"] = len(pd.read_parquet(out)) / n
    return res


def run_one(
    folder: Path, gyro: str, repeat: int, params: DetectParams | None = None
) -> dict[str, Any]:
    session = load_session(folder)
    params = params or DetectParams()
    t0 = time.perf_counter()
    res = detect_session(session, params, gyro=gyro)
    wall = time.perf_counter() - t0
    out = evaluate(res.table, session.truth or {"frames": []})
    out.update(trust(res.table, session.truth or {"frames": []}))
    if "source" in res.table.columns:
        out["source"] = {str(k): int(v) for k, v in res.table["source"].value_counts().items()}
    if "reason" in res.table.columns:
        out["reason"] = {str(k): int(v) for k, v in res.table["reason"].value_counts().items()}
    # The same measures over the subsets a consumer would keep (flags, quality column).
    for name, keep in (("not_faint", ~res.table["faint"]), ("quality_ok", res.table["quality_ok"])):
        sub = evaluate(res.table[keep], session.truth or {"frames": []})
        for k in ("precision_unclipped", "recall_inside", "endpoint_error_median_px"):
            out[f"{name}_{k}"] = sub[k]
    frames = [session.read_image(i) for i in range(len(session.frames))]
    out.update(speed(frames, params, repeat))
    out.update(
        {
            "session_wall_s": wall,
            "frames": len(frames),
            "streaks": len(res.table),
            "orientation_sources": res.summary["orientation_sources"],
            "flags": res.summary["flags"],
            "gyro_timeshift_s": res.summary.get("gyro_timeshift_s"),
        }
    )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["clean", "realistic", "hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--gyro", default="auto", choices=("auto", "off"))
    ap.add_argument("--repeat", type=int, default=3, help="speed passes over the frames")
    ap.add_argument("--work", type=Path, default=ROOT / "bench_out" / "detect")
    ap.add_argument("--session", type=Path, default=None, help="benchmark this session only")
    ap.add_argument(
        "--params",
        type=Path,
        default=None,
        help="detection parameters (YAML, as `blurtrack detect --params`), e.g. "
        "`gyro_template: false` for the first pass alone",
    )
    ap.add_argument(
        "--command",
        action="store_true",
        help="time the whole `blurtrack detect` command against the file baseline",
    )
    ap.add_argument(
        "--before",
        type=Path,
        default=None,
        metavar="ROOT",
        help="with --command: also time the command of the code tree at ROOT (e.g. "
        "`git archive` of main unpacked there), interleaved, with this interpreter",
    )
    args = ap.parse_args()
    params = DetectParams.from_yaml(args.params) if args.params is not None else None
    if args.command:
        args.work.mkdir(parents=True, exist_ok=True)
        runs = []
        for preset in args.presets:
            for seed in args.seeds:
                folder = simulate(args.work, preset, args.frames, seed)
                r = {
                    "preset": preset,
                    "seed": seed,
                    **command_speed(
                        folder, args.repeat, args.work, args.before, args.params, args.gyro
                    ),
                }
                print(json.dumps(r), file=sys.stderr)
                runs.append(r)
        print(json.dumps({"command_runs": runs}, indent=2))
        return 0
    results: dict[str, Any] = {"runs": []}
    if args.session is not None:
        one = run_one(args.session, args.gyro, args.repeat, params)
        one.pop("_errors", None)
        one.pop("_counts", None)
        one.pop("_trust_counts", None)
        results["runs"].append({"session": str(args.session), **one})
    else:
        args.work.mkdir(parents=True, exist_ok=True)
        for preset in args.presets:
            for seed in args.seeds:
                folder = simulate(args.work, preset, args.frames, seed)
                r = run_one(folder, args.gyro, args.repeat, params)
                results["runs"].append({"preset": preset, "seed": seed, **r})
                print(
                    json.dumps(
                        {
                            "preset": preset,
                            "seed": seed,
                            **{
                                k: r[k]
                                for k in (
                                    "endpoint_error_median_px",
                                    "endpoint_error_p95_px",
                                    "orientation_correct",
                                    "recall_inside",
                                    "precision_unclipped",
                                    "ok_precision",
                                    "ok_coverage",
                                    "ok_detections",
                                    "ok_wrong",
                                    "time_ratio",
                                    "detect_fps",
                                    "not_faint_precision_unclipped",
                                    "quality_ok_precision_unclipped",
                                    "quality_ok_recall_inside",
                                    "quality_ok_endpoint_error_median_px",
                                )
                            },
                        }
                    ),
                    file=sys.stderr,
                )
        summary = {}
        for preset in args.presets:
            rs = [r for r in results["runs"] if r["preset"] == preset]
            keys = (
                "endpoint_error_median_px",
                "endpoint_error_p95_px",
                "mid_error_median_px",
                "mid_error_p95_px",
                "orientation_correct",
                "recall_inside",
                "precision_unclipped",
                "detect_fps",
                "baseline_fps",
                "time_ratio",
            )
            summary[preset] = {k: float(np.median([r[k] for r in rs])) for k in keys}
            summary[preset]["worst_orientation_correct"] = min(r["orientation_correct"] for r in rs)
            # Pooled over the seeds: every matched endpoint and every streak counts once.
            err = np.concatenate([r["_errors"] for r in rs])
            c = np.sum([r["_counts"] for r in rs], axis=0)
            summary[preset]["pooled"] = {
                "endpoint_error_median_px": float(np.median(err)),
                "endpoint_error_p95_px": float(np.percentile(err, 95)),
                "orientation_correct": float(c[0] / max(c[1], 1)),
                "recall_inside": float(c[2] / max(c[3], 1)),
                "precision_unclipped": float(c[4] / max(c[5], 1)),
                "endpoints": int(err.size),
            }
            light = [r for r in rs if "ok_precision_light" in r]
            if light:
                n_ok = sum(r["ok_detections"] for r in light)
                wrong = sum(r["ok_wrong_light"] for r in light)
                summary[preset]["pooled_ok_precision_light"] = 1.0 - wrong / max(n_ok, 1)
            t = np.sum([r["_trust_counts"] for r in rs], axis=0)
            summary[preset]["pooled"].update(
                {
                    "ok_precision": float(t[0] / max(t[1], 1)),
                    "ok_coverage": float(t[2] / max(t[3], 1)),
                    "ok_detections": int(t[1]),
                    "ok_wrong": int(t[1] - t[0]),
                }
            )
        for r in results["runs"]:
            r.pop("_errors", None)
            r.pop("_counts", None)
            r.pop("_trust_counts", None)
        results["median_over_seeds"] = summary
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
