"""Calibration accuracy and speed over simulator presets and seeds (truth known).

For each preset and seed: simulate a session (``blurtrack simulate``), calibrate from the true
streaks (``--streaks truth``, the default: isolates calibration error from detection error) or
from the streaks ``blurtrack detect`` finds in the frames (``--streaks detected``: the whole
pipeline, detection errors and wrongly resolved start/end included), and compare every estimate
with the truth and its 1-sigma.
Baselines measured in the same run: the initial guess's errors and hold-out endpoint error, and
the time of one numpy evaluation of the residual over all streaks (speed ratio).
Accuracy against the amount of data: ``--frames 100,400`` runs every preset and seed at each
recording length (the 1-sigma should shrink about as ``1/sqrt(frames)``). Speed against the
number of streaks: the first session calibrated on 25, 50 and 100 % of its frames. Prints one
JSON document.

    PYTHONPATH=. python bench/bench_calibrate.py --presets clean,realistic --seeds 0,1,2 \\
        --frames 100,400 --work /tmp/bench_calib [--fit ...] [--centreline] \\
        [--streaks detected]

``--command`` times the whole ``blurtrack calibrate`` command (a subprocess, what a user runs:
the session without truth.yaml, the true streaks as its streak table) on sessions simulated at
each ``--imu-rates`` gyro rate (``--imu-rate`` of ``blurtrack simulate``) and reports wall and
CPU seconds, time per track, stage times, the axis search's decision and margin, the written
calibration's errors against the truth and the |z| of each estimate (medians over ``--repeat``
runs and seeds); the baseline timed in the same run is the lowest gyro rate
(``per_track_ratio``):

    PYTHONPATH=. python bench/bench_calibrate.py --command --presets realistic --seeds 0 \\
        --frames 150 --imu-rates 200,1000 --work /tmp/bench_calib

``--baseline-repo DIR`` (a checkout of older code, e.g. ``git archive COMMIT | tar -x -C DIR``)
runs the same command from there right after each run (same sessions, same machine load) and
reports the speed-up.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from calibrate_command import command_bench
from calibrate_common import REPO, TARGETS, _errors, effective_rotation, simulate

from blurtrack.geometry.calibration import Calibration
from blurtrack.io import streaks as streak_table
from blurtrack.io.calibration import calibration_from_dict
from blurtrack.io.session import load_session
from calib.data import relative_gyro, streaks_from_table
from calib.fit import RESIDUALS, FitOptions, calibrate
from calib.params import DEFAULT_FIT, theta_from
from calib.problem import ResidualModel, choose_substeps


def detect(session_dir: Path) -> tuple[Path, float]:
    """``blurtrack detect`` over the session (once; the table is kept beside the frames).
    Returns the table's path and the command's wall seconds (0 when it was already there)."""
    out = session_dir / "streaks.parquet"
    if out.is_file():
        return out, 0.0
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "blurtrack", "detect", str(session_dir), "--out", str(out)],
        check=True,
        capture_output=True,
        cwd=REPO,
    )
    return out, time.perf_counter() - t0


def _z_scores(res, truth: Calibration, initial: Calibration) -> dict[str, float]:
    """|error| / sigma of every estimated scalar with a known truth (not rotation or scale)."""
    t = theta_from(truth)
    names = ("timeshift_s", "fx", "fy", "cx", "cy", "readout_s", "bias_x", "bias_y", "bias_z")
    return {
        n: abs(res.values[n] - t[i]) / res.sigma[n]
        for i, n in enumerate(names)
        if n in res.sigma and res.sigma[n] > 0
    }


def _sigmas(res, truth: Calibration) -> dict[str, float]:
    """1-sigma in the units of :data:`TARGETS` (focal lengths relative, bias the largest axis)."""
    s = res.sigma
    fx, fy = truth.camera.intrinsics[:2]
    out = {
        "timeshift_s": s.get("timeshift_s"),
        "fx_rel": s.get("fx", np.nan) / fx,
        "fy_rel": s.get("fy", np.nan) / fy,
        "cx": s.get("cx"),
        "cy": s.get("cy"),
        "readout_s": s.get("readout_s"),
        "bias_radps": max(s.get(f"bias_{a}", np.nan) for a in "xyz"),
    }
    return {k: float(np.nan if v is None else v) for k, v in out.items()}


def run_one(
    session_dir: Path, options: FitOptions, frame_fraction: float = 1.0, source: str = "truth"
) -> dict:
    from calib.centreline import CENTRE_POINTS

    session = load_session(session_dir)
    detect_wall = 0.0
    if source == "detected":
        path, detect_wall = detect(session_dir)
        table = streak_table.read(path)
    else:
        table = streak_table.from_truth(session.truth)
    if frame_fraction < 1.0:
        nf = round(len(session.frames) * frame_fraction)
        table = table[table["frame"] < nf]
    streaks = streaks_from_table(
        table, session.frames, centre_k=CENTRE_POINTS if options.centreline else 0
    )
    truth = calibration_from_dict(session.truth["calibration"], "truth.yaml")
    initial = session.initial_calibration()
    gyro = session.gyro()
    # Baseline: one numpy residual evaluation over all streaks (the fit's unit of work).
    g = relative_gyro(gyro.upsampled(options.gyro_upsample), streaks.t0_s)
    model = ResidualModel(
        g,
        initial.R_cam_imu,
        (),
        initial.camera.height,
        choose_substeps(streaks, initial.camera.height, 0.05),
    )
    t0 = time.process_time()
    r0 = model.residual_np(theta_from(initial), streaks)
    base_cpu = time.process_time() - t0
    c0, w0 = time.process_time(), time.perf_counter()
    res = calibrate(streaks, gyro, initial, options)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    err = _errors(res.calibration, truth, effective_rotation(session.truth, truth.R_cam_imu))
    ok = {k: abs(v) <= TARGETS[k] for k, v in err.items() if k in TARGETS}
    z = _z_scores(res, truth, initial)
    return {
        "sigma": _sigmas(res, truth),
        "streaks": source,
        "detect_wall_s": detect_wall,
        "n_flipped": res.n_flipped,
        "session": session_dir.name,
        "n_streaks": len(streaks),
        "n_frames": streaks.n_frames,
        "status": res.status,
        "iterations": res.iterations,
        "cpu_s": cpu,
        "wall_s": wall,
        "baseline_residual_cpu_s": base_cpu,
        "cpu_over_baseline": cpu / max(base_cpu, 1e-9),
        "error": err,
        "within_target": ok,
        "all_within_target": all(ok.values()),
        "initial_error": _errors(initial, truth),
        "initial_mean_endpoint_error_px": float(np.mean(np.linalg.norm(r0, axis=1))),
        "holdout_mean_px": res.holdout.mean_px,
        "holdout_median_px": res.holdout.median_px,
        "holdout_p95_px": res.holdout.p95_px,
        "train_mean_px": res.train.mean_px,
        "z_scores": z,
        "max_z": max(z.values()) if z else None,
        "within_3sigma": all(v <= 3 for v in z.values()),
        "n_outliers": res.n_outliers,
        "warnings": list(res.warnings),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="clean,realistic")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument(
        "--frames",
        default="100",
        help="recording length(s) in frames, comma-separated (default 100)",
    )
    ap.add_argument("--fit", default=DEFAULT_FIT)
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_calib"))
    ap.add_argument("--no-scaling", action="store_true", help="skip time vs streak count")
    ap.add_argument("--centreline", action="store_true", help="centre-line residuals too")
    ap.add_argument("--frame-noise", action="store_true", help="frame-noise GLS refinement")
    ap.add_argument(
        "--residuals",
        choices=RESIDUALS,
        default=FitOptions().residuals,
        help="final-stage residuals (endpoints, tracks or both)",
    )
    ap.add_argument(
        "--streaks",
        choices=("truth", "detected"),
        default="truth",
        help="calibrate from the simulator's true streaks or from blurtrack detect",
    )
    ap.add_argument(
        "--command",
        action="store_true",
        help="time the whole 'blurtrack calibrate' command (subprocess; true streaks as the "
        "session's streak table, truth.yaml hidden) instead "
        "of the library call, at each --imu-rates gyro rate",
    )
    ap.add_argument("--imu-rates", default="200,1000", help="gyro rates (Hz) for --command")
    ap.add_argument("--repeat", type=int, default=1, help="runs per session (--command)")
    ap.add_argument(
        "--baseline-repo",
        type=Path,
        default=None,
        help="--command: also run the command from this checkout (e.g. `git archive` of an "
        "older commit), interleaved with this one's runs",
    )
    args = ap.parse_args()
    if args.command:
        print(json.dumps(command_bench(args), indent=1, default=float))
        return 0
    opts = FitOptions(
        fit=args.fit,
        centreline=args.centreline,
        frame_noise=args.frame_noise,
        residuals=args.residuals,
    )
    runs = []
    lengths = [int(f) for f in args.frames.split(",")]
    for preset in args.presets.split(","):
        for frames in lengths:
            for seed in (int(s) for s in args.seeds.split(",")):
                d = simulate(args.work / f"{preset}_s{seed}_f{frames}", preset, seed, frames)
                run = run_one(d, opts, source=args.streaks)
                run.update(preset=preset, seed=seed, frames=frames)
                runs.append(run)
                print(
                    f"# {preset} {frames} frames seed {seed}: {run['status']}, "
                    f"{run['cpu_s']:.1f} s cpu, hold-out {run['holdout_mean_px']:.3f} px, "
                    f"max z {run['max_z']:.2f}",
                    file=sys.stderr,
                )
    scaling = []
    if not args.no_scaling and runs:
        first = args.work / runs[0]["session"]
        for frac in (0.25, 0.5, 1.0):
            r = run_one(first, opts, frac, source=args.streaks)
            scaling.append(
                {
                    "frames": r["n_frames"],
                    "n_streaks": r["n_streaks"],
                    "cpu_s": r["cpu_s"],
                    "wall_s": r["wall_s"],
                    "cpu_over_baseline": r["cpu_over_baseline"],
                }
            )
    by_preset = {}
    for key in sorted({(r["preset"], r["frames"]) for r in runs}):
        rs = [r for r in runs if (r["preset"], r["frames"]) == key]
        by_preset[f"{key[0]}/{key[1]}"] = {
            "runs": len(rs),
            "all_within_target": sum(r["all_within_target"] for r in rs),
            "within_3sigma": sum(r["within_3sigma"] for r in rs),
            "median_holdout_mean_px": float(np.median([r["holdout_mean_px"] for r in rs])),
            "median_cpu_s": float(np.median([r["cpu_s"] for r in rs])),
            "max_abs_error": {k: float(max(abs(r["error"][k]) for r in rs)) for k in TARGETS},
            "median_sigma": {
                k: float(np.median([r["sigma"][k] for r in rs])) for k in rs[0]["sigma"]
            },
            "max_z": float(max(r["max_z"] or 0.0 for r in rs)),
            "median_cpu_over_baseline": float(np.median([r["cpu_over_baseline"] for r in rs])),
            "median_initial_endpoint_error_px": float(
                np.median([r["initial_mean_endpoint_error_px"] for r in rs])
            ),
        }
    z_all = [v for r in runs for v in r["z_scores"].values()]
    print(
        json.dumps(
            {
                "fit": args.fit,
                "streaks": args.streaks,
                "residuals": args.residuals,
                "centreline": args.centreline,
                "frame_noise": args.frame_noise,
                "targets": TARGETS,
                "by_preset": by_preset,
                "fraction_of_estimates_within_3sigma": float(np.mean(np.array(z_all) <= 3))
                if z_all
                else None,
                "fraction_of_runs_all_within_3sigma": float(
                    np.mean([r["within_3sigma"] for r in runs])
                )
                if runs
                else None,
                "scaling": scaling,
                "runs": runs,
            },
            indent=1,
            default=float,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
