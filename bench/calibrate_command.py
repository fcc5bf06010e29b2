"""``bench_calibrate.py --command``: the whole ``blurtrack calibrate`` command a user runs,
timed as a subprocess, with the written calibration's errors against the simulator's truth."""

from __future__ import annotations

import argparse
import functools
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from calibrate_common import REPO, TARGETS, _errors, effective_rotation, simulate

from blurtrack.io import streaks as streak_table
from blurtrack.io.calibration import calibration_from_dict, read_calibration
from blurtrack.io.session import load_session


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

    from calib.truth import truth_values

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
    truth = calibration_from_dict(session.truth["calibration"], "truth.yaml")
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
        cal = read_calibration(out)
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
