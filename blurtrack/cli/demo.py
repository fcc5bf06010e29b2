"""``blurtrack demo --out DIR``: the whole pipeline on the embedded simulated rig (``make demo``).

simulate → detect → calibrate → report → import the real recordings → synthesise a small
dataset with the fitted calibration → train GAMD briefly → before/after picture. Each step
runs the same command a user would type; the first failing step stops the demo with its
one-line reason and a non-zero exit.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DEFAULT_DATA = REPO.parent / "shared" / "data"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on the simulated rig")
    p.add_argument("--out", type=Path, default=Path("demo_out"))
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help="the shared real data (default: ../shared/data beside the repository)")
    p.add_argument("--frames", type=int, default=40, help="simulated frames")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--train-steps", type=int, default=150)
    p.set_defaults(func=run)


def _step(title: str, fn: Callable[[], int]) -> None:
    from blurtrack.errors import BlurTrackError

    print(f"\n== {title}", flush=True)
    t0 = time.perf_counter()
    rc = fn()
    if rc != 0:
        raise BlurTrackError(f"demo step '{title}' failed with exit status {rc}")
    print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)


def _print_calibration(calib_path: Path, session: Path) -> None:
    from blurtrack.calibration import Calibration
    from blurtrack.session import load_session

    fit = Calibration.from_yaml(calib_path)
    s = load_session(session)
    guess = s.initial_calibration()
    truth = Calibration.from_dict(s.truth["calibration"]) if s.truth else None
    sig = fit.sigma

    def row(name: str, g: float, f: float, t: float | None, s_key: str, unit: str,
            scale: float = 1.0) -> None:
        sd = sig.get(s_key)
        sd_txt = f"± {float(sd) * scale:.4g}" if isinstance(sd, (int, float)) else ""
        t_txt = f"{t * scale:12.4f}" if t is not None else "           -"
        err = f"{(f - t) * scale:+.4f}" if t is not None else ""
        print(f"   {name:<14}{g * scale:12.4f}{f * scale:12.4f} {sd_txt:<12}{t_txt}  {err} {unit}")

    print(f"   {'parameter':<14}{'guess':>12}{'fitted':>12} {'1-sigma':<12}{'truth':>12}  error")
    names = ("fx", "fy", "cx", "cy")
    for k, n in enumerate(names):
        row(n, guess.camera.intrinsics[k], fit.camera.intrinsics[k],
            truth.camera.intrinsics[k] if truth else None, n, "px")
    row("timeshift", guess.timeshift_cam_imu_s, fit.timeshift_cam_imu_s,
        truth.timeshift_cam_imu_s if truth else None, "timeshift_cam_imu", "ms", 1e3)
    row("readout", guess.camera.readout_s, fit.camera.readout_s,
        truth.camera.readout_s if truth else None, "readout_s", "ms", 1e3)
    for k, axis in enumerate("xyz"):
        row(f"bias_{axis}", float(guess.gyro_bias_radps[k]), float(fit.gyro_bias_radps[k]),
            float(truth.gyro_bias_radps[k]) if truth else None, f"gyro_bias_{axis}",
            "mrad/s", 1e3)
    if truth is not None:
        from blurtrack.rotation import rotation_angle_deg

        print(f"   rotation error: guess {float(rotation_angle_deg(guess.R_cam_imu, truth.R_cam_imu)):.3f}°,"
              f" fitted {float(rotation_angle_deg(fit.R_cam_imu, truth.R_cam_imu)):.4f}°")


def run(args: argparse.Namespace) -> int:
    from blurtrack.cli import main as bt
    from blurtrack.errors import BlurTrackError

    out: Path = args.out
    data: Path = args.data
    if not data.is_dir():
        raise BlurTrackError(f"shared data not found at {data} (use --data)")
    if out.exists() and any(out.iterdir()):
        raise BlurTrackError(f"{out} is not empty: remove it or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    sim = out / "sim"
    t_start = time.perf_counter()

    _step("simulate a laser-grid session (realistic preset)", lambda: bt(
        ["simulate", str(sim), "--preset", "realistic", "--frames", str(args.frames),
         "--seed", str(args.seed)]))
    _step("detect the streaks", lambda: bt(
        ["detect", str(sim), "--out", str(sim / "streaks.parquet"),
         "--overlay", str(out / "detect.png")]))
    _step("calibrate with CasADi", lambda: bt(
        ["calibrate", str(sim), "--out", str(out / "calib.yaml")]))
    _print_calibration(out / "calib.yaml", sim)
    _step("endpoint-error report", lambda: bt(
        ["report", str(sim), "--calib", str(out / "calib.yaml"), "--out", str(out / "report")]))
    real = data / "real"
    _step("import the DeepGyro recording (predicted trajectories drawn)", lambda: bt(
        ["import", "deepgyro", str(real / "deepgyro-shield"), str(out / "deepgyro"),
         "--overlays", "7"]))
    _step("import the MARS logger recording (predicted trajectories drawn)", lambda: bt(
        ["import", "marslogger", str(real / "marslogger-phone"), str(out / "marslogger"),
         "--overlays", "10"]))
    _step("synthesise calibrated training triplets", lambda: _synth(out, data))
    _step("train GAMD briefly and deblur a test image", lambda: _gamd(out, args.train_steps))
    print(f"\ndemo finished in {time.perf_counter() - t_start:.0f} s; outputs:")
    for name, what in [
        ("sim/", "simulated session with truth.yaml"),
        ("detect.png", "detected streaks over a frame"),
        ("calib.yaml", "fitted calibration (Kalibr keys)"),
        ("report/index.html", "endpoint-error report"),
        ("deepgyro/overlays/", "predicted trajectories on the DeepGyro frames"),
        ("marslogger/overlays/", "predicted trajectories on the MARS logger frames"),
        ("dataset/", "training triplets (sharp, blur, heat maps)"),
        ("gamd/before_after.png", "blurred | GAMD output | sharp"),
    ]:
        print(f"   {out / name}: {what}")
    return 0


def _synth(out: Path, data: Path) -> int:
    from blurtrack.calibration import Calibration
    from blurtrack.synth.demo import demo_dataset

    calib = Calibration.from_yaml(out / "calib.yaml")
    res = demo_dataset(out / "dataset", data, count=24, size=(256, 192), calib=calib)
    print(f"   {json.dumps({k: v for k, v in res.items() if not isinstance(v, (dict, list))})}")
    return 0


def _gamd(out: Path, steps: int) -> int:
    from gamd.demo import demo_train

    res = demo_train(out / "dataset", out / "gamd", steps=steps)
    print(f"   {json.dumps(res)}")
    return 0
