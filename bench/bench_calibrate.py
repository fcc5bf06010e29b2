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
import functools
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from blurtrack.geometry.rotation import rotation_angle_deg
from blurtrack.io import streaks as streak_table
from blurtrack.io.calibration import Calibration
from blurtrack.io.session import load_session
from calib.data import relative_gyro, streaks_from_table
from calib.fit import RESIDUALS, FitOptions, calibrate
from calib.params import DEFAULT_FIT, theta_from
from calib.problem import ResidualModel, choose_substeps

REPO = Path(__file__).resolve().parents[1]
SHAKE = REPO.parent / "shared" / "data" / "real" / "gyrodeblurnet-shake" / "gyro_train.txt"
TARGETS = {
    "timeshift_s": 1e-4,
    "fx_rel": 1e-3,
    "fy_rel": 1e-3,
    "cx": 0.5,
    "cy": 0.5,
    "readout_s": 2e-4,
    "bias_radps": 2e-4,
    "rotation_deg": 0.1,
}


def simulate(
    out: Path, preset: str, seed: int, frames: int, imu_rate_hz: float | None = None
) -> Path:
    if (out / "truth.yaml").is_file():
        return out
    cmd = [
        sys.executable,
        "-m",
        "blurtrack",
        "simulate",
        str(out),
        "--preset",
        preset,
        "--frames",
        str(frames),
        "--seed",
        str(seed),
    ]
    if SHAKE.is_file():
        cmd += ["--shake", str(SHAKE)]
    if imu_rate_hz is not None:
        cmd += ["--imu-rate", f"{imu_rate_hz:g}"]
    subprocess.run(cmd, check=True, capture_output=True, cwd=REPO)
    return out


def user_session(session_dir: Path, work: Path) -> Path:
    """What a user calibrates: the simulated session without its ``truth.yaml`` (symlinks to
    the rest) and the simulator's true streaks written as its ``streaks.parquet``, so the
    command reads a streak table as it does after ``blurtrack detect`` and no truth (parsing
    a 150-frame truth.yaml alone takes about 10 s)."""
    out = work / "user" / session_dir.name
    if (out / "streaks.parquet").is_file():
        return out
    out.mkdir(parents=True, exist_ok=True)
    for item in session_dir.iterdir():
        if item.name not in ("truth.yaml", "streaks.parquet") and not (out / item.name).exists():
            (out / item.name).symlink_to(item.resolve())
    table = streak_table.from_truth(load_session(session_dir).truth)
    streak_table.write(table, out / "streaks.parquet")
    return out


@functools.cache
def _session(session_dir: Path):
    """The simulated session with its truth, parsed once (a 1200-frame truth.yaml takes
    minutes to parse)."""
    return load_session(session_dir)


def run_command(
    session_dir: Path, user_dir: Path, out_dir: Path, extra: list[str], repo: Path = REPO
) -> dict:
    """The WHOLE ``blurtrack calibrate`` command a user runs (a subprocess in ``repo``, on
    :func:`user_session`): wall and CPU seconds (the child's user + system), its stage
    timings (summary.json), and the written calibration's errors against the simulator's
    truth with the |z| of each estimate."""
    import resource

    from calib.cli import truth_values

    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / "calib.yaml"
    # The command never overwrites its outputs: remove an earlier run's (a repeat would be
    # refused in a second and read the earlier run's summary).
    for old in out_dir.glob("calib*"):
        old.unlink()
    cmd = [sys.executable, "-m", "blurtrack", "calibrate", str(user_dir), "--out", str(out)]
    cmd += extra
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=repo)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if proc.returncode != 0 and not (out_dir / "calib.failed.summary.json").is_file():
        raise RuntimeError(f"calibrate exited {proc.returncode}: {proc.stderr[-2000:]}")
    name = "calib.summary.json" if proc.returncode == 0 else "calib.failed.summary.json"
    summary = json.loads((out_dir / name).read_text())
    session = _session(session_dir)
    truth = Calibration.from_dict(session.truth["calibration"], "truth.yaml")
    run: dict = {
        "session": session_dir.name,
        "returncode": proc.returncode,
        "wall_s": wall,
        "cpu_s": cpu,
        "status": summary["status"],
        "n_tracks": summary.get("n_tracks", 0),
        "n_streaks": summary["train_all"]["n"] + summary["holdout_all"]["n"],
        "gyro_rate_hz": session.gyro().rate_hz,
        "iterations": summary["iterations"],
        "stage_s": summary["timings_s"],
        "holdout_mean_px": summary["holdout_inliers"]["mean_px"],
    }
    axes = summary.get("axes")  # the axis search's decision (absent under --axes session)
    if axes:
        run["axes"] = {
            "R_cam_imu": axes["winner"]["R_cam_imu"],
            "timeshift_s": axes["winner"]["timeshift_s"],
            "score_px": axes["winner"]["score_px"],
            "margin": axes["margin"],
        }
    n_units = run["n_tracks"] or run["n_streaks"]
    run["wall_per_track_ms"] = 1e3 * wall / max(n_units, 1)
    run["cpu_per_track_ms"] = 1e3 * cpu / max(n_units, 1)
    if out.is_file():
        cal = Calibration.from_yaml(out)
        err = _errors(cal, truth, effective_rotation(session.truth, truth.R_cam_imu))
        run["error"] = err
        run["within_target"] = {k: abs(v) <= TARGETS[k] for k, v in err.items() if k in TARGETS}
        tv = truth_values(session, session.initial_calibration()) or {}
        z = {
            k: abs(summary["values"][k] - tv[k]) / s
            for k, s in summary["sigma"].items()
            if k in tv and s > 0 and not k.startswith(("rot", "scale"))
        }
        run["z_scores"] = z
        run["max_z"] = max(z.values()) if z else None
        run["within_3sigma"] = all(v <= 3 for v in z.values())
    return run


def command_bench(args: argparse.Namespace) -> dict:
    """``--command``: the whole command on each preset, length, gyro rate and seed, repeated
    ``--repeat`` times (medians). The baseline timed in the same run is the same command on the
    lowest gyro rate: ``per_track_ratio`` is time per track at each rate over that. With
    ``--baseline-repo`` the same command from that checkout runs right after each run of this
    one (same sessions, same load): groups ``baseline:…``, and ``speedup`` (baseline time over
    this one's)."""
    runs = []
    rates = [float(r) for r in args.imu_rates.split(",")]
    extra = ["--fit", args.fit, "--residuals", args.residuals]
    codes = [("current", REPO)]
    if args.baseline_repo is not None:
        codes.append(("baseline", args.baseline_repo.resolve()))
    for preset in args.presets.split(","):
        for frames in (int(f) for f in args.frames.split(",")):
            for rate in rates:
                for seed in (int(s) for s in args.seeds.split(",")):
                    name = f"{preset}_s{seed}_f{frames}_g{rate:g}"
                    d = simulate(args.work / name, preset, seed, frames, rate)
                    user = user_session(d, args.work)
                    reps: dict[str, list[dict]] = {c: [] for c, _ in codes}
                    for _ in range(args.repeat):
                        for code, repo in codes:
                            out = args.work / "out" / code / name
                            reps[code].append(run_command(d, user, out, extra, repo))
                    for code, _ in codes:
                        run = dict(reps[code][-1])
                        for key in ("wall_s", "cpu_s", "wall_per_track_ms", "cpu_per_track_ms"):
                            run[key] = float(np.median([r[key] for r in reps[code]]))
                            run[key + "_all"] = [r[key] for r in reps[code]]
                        run.update(
                            preset=preset, seed=seed, frames=frames, imu_rate_hz=rate, code=code
                        )
                        runs.append(run)
                        print(
                            f"# {code} {name}: {run['status']}, {run['wall_s']:.1f} s wall, "
                            f"{run['cpu_s']:.1f} s cpu, {run['wall_per_track_ms']:.3f} ms/track, "
                            f"max z {run.get('max_z')}",
                            file=sys.stderr,
                        )
    groups = {}
    for key in sorted({(r["code"], r["preset"], r["frames"], r["imu_rate_hz"]) for r in runs}):
        rs = [r for r in runs if (r["code"], r["preset"], r["frames"], r["imu_rate_hz"]) == key]
        prefix = "" if key[0] == "current" else f"{key[0]}:"
        groups[f"{prefix}{key[1]}/{key[2]}/{key[3]:g}Hz"] = {
            "runs": len(rs),
            "median_wall_s": float(np.median([r["wall_s"] for r in rs])),
            "median_cpu_s": float(np.median([r["cpu_s"] for r in rs])),
            "median_wall_per_track_ms": float(np.median([r["wall_per_track_ms"] for r in rs])),
            "median_cpu_per_track_ms": float(np.median([r["cpu_per_track_ms"] for r in rs])),
            "median_n_tracks": float(np.median([r["n_tracks"] for r in rs])),
            "median_holdout_mean_px": float(np.median([r["holdout_mean_px"] for r in rs])),
            "max_abs_error": {
                k: float(max(abs(r["error"][k]) for r in rs if "error" in r)) for k in TARGETS
            },
            "within_3sigma": sum(bool(r.get("within_3sigma")) for r in rs),
            "axes_margin": [r["axes"]["margin"] for r in rs if "axes" in r],
            "axes_R_cam_imu": [r["axes"]["R_cam_imu"] for r in rs if "axes" in r][:1],
            "max_z": float(max(r.get("max_z") or 0.0 for r in rs)),
            "median_stage_s": {
                k: float(np.median([r["stage_s"].get(k, np.nan) for r in rs]))
                for k in rs[0]["stage_s"]
            },
        }
    base = {}
    speedup = {}
    for name, g in groups.items():
        prefix, _, rest = name.rpartition(":")
        preset, frames, _ = rest.split("/")
        ref = groups[f"{prefix + ':' if prefix else ''}{preset}/{frames}/{min(rates):g}Hz"]
        base[name] = {
            k: g[f"median_{k}_per_track_ms"] / ref[f"median_{k}_per_track_ms"]
            for k in ("wall", "cpu")
        }
        if prefix:
            cur = groups[rest]
            speedup[rest] = {k: g[f"median_{k}_s"] / cur[f"median_{k}_s"] for k in ("wall", "cpu")}
    return {
        "mode": "command",
        "by_group": groups,
        "per_track_ratio": base,
        "speedup": speedup,
        "runs": runs,
    }


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


def effective_rotation(truth: dict, R_true: np.ndarray) -> np.ndarray:
    """The camera–IMU rotation the gyro data define: ``R_true Qᵀ`` with ``M = P Q`` the polar
    decomposition of the simulator's gyro scale/cross-axis matrix (``ω_meas = M R_trueᵀ ω``).
    A rotation of the gyro's own axes cannot be told apart from the mounting rotation."""
    M = np.array(
        ((truth.get("simulator") or {}).get("gyro") or {}).get("scale_matrix", np.eye(3)), float
    )
    U, _, Vt = np.linalg.svd(M)
    return R_true @ (U @ Vt).T


def _errors(
    cal: Calibration, truth: Calibration, R_eff: np.ndarray | None = None
) -> dict[str, float]:
    t, e = theta_from(truth), theta_from(cal)
    R_ref = truth.R_cam_imu if R_eff is None else R_eff
    return {
        "timeshift_s": e[0] - t[0],
        "fx_rel": e[1] / t[1] - 1,
        "fy_rel": e[2] / t[2] - 1,
        "cx": e[3] - t[3],
        "cy": e[4] - t[4],
        "readout_s": e[5] - t[5],
        "bias_radps": float(np.max(np.abs(e[6:9] - t[6:9]))),
        "rotation_deg": float(rotation_angle_deg(cal.R_cam_imu, R_ref)),
        "rotation_vs_stated_truth_deg": float(rotation_angle_deg(cal.R_cam_imu, truth.R_cam_imu)),
    }


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
    truth = Calibration.from_dict(session.truth["calibration"], "truth.yaml")
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
