"""Benchmark: a sustained 1 kHz IMU plus a 30 fps 1280 x 720 camera recorded on one core.

Each measurement runs in a child process pinned to one CPU (``os.sched_setaffinity``) with the
virtual devices (``sim://imu`` on a real pty, ``sim://camera``) in the same process:

- ``devices``: the baseline, measured in the same run: the devices stream, the IMU driver
  decodes and timestamps, frames are grabbed (nothing is logged or written);
- ``record``: the full recorder (decode, timestamp, PNG-encode, write the MCAP log, flush every
  0.25 s).

Printed as JSON: per mode the median over repetitions of CPU use (fraction of one core), sample
and frame counts against what the devices produced, drops, CRC errors; plus the recorder's CPU
overhead over the baseline. Usage: ``python bench/bench_record.py [--duration 8] [--reps 2]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
IMU_URL = "sim://imu?rate=1000"
# sensor noise (sigma 4 grey levels) makes frames compress like a real camera's
CAM_URL = "sim://camera?fps=30&width=1280&height=720&exposure_ms=10&noise=4"


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child(mode: str, duration_s: float) -> dict:
    from rigs.camera import open_camera
    from rigs.imu import open_imu
    from rigs.recorder import Recorder, RecorderConfig

    cpu = sorted(os.sched_getaffinity(0))[-1]
    os.sched_setaffinity(0, {cpu})
    imu = open_imu(IMU_URL)
    cam = open_camera(CAM_URL)
    wall0, cpu0 = time.monotonic(), _cpu_s()
    out: dict = {"mode": mode, "cpu": cpu}
    if mode == "record":
        with tempfile.TemporaryDirectory() as d:
            rec = Recorder(
                Path(d) / "bench.mcap", imu, cam, {}, RecorderConfig(duration_s=duration_s)
            )
            res = rec.run()
            out["log_mb_per_s"] = res.status.log_bytes / 1e6 / res.status.elapsed_s
        s = res.status
        out.update(
            imu_samples=s.imu_samples,
            frames=s.frames,
            imu_dropped=s.imu_dropped,
            imu_crc_errors=s.imu_crc_errors,
            camera_dropped=s.camera_dropped,
            error=res.error,
            imu_rate_hz=s.imu_rate_hz,
            fps=s.fps,
            recording_s=s.elapsed_s,
        )
    else:
        stop = threading.Event()
        counts = {"imu": 0, "frames": 0}

        def read_imu() -> None:
            while not stop.is_set():
                counts["imu"] += len(imu.read())

        t = threading.Thread(target=read_imu, daemon=True)
        t.start()
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            if cam.read() is not None:
                counts["frames"] += 1
        stop.set()
        t.join()
        out.update(
            imu_samples=counts["imu"],
            frames=counts["frames"],
            imu_dropped=imu.stats["dropped"],
            imu_crc_errors=imu.stats["crc_errors"],
            camera_dropped=cam.frames_dropped,
            error=None,
        )
    wall, cpu_used = time.monotonic() - wall0, _cpu_s() - cpu0
    produced = imu.device.sent_index.size if imu.device is not None else 0
    imu.close()
    cam.close()
    out.setdefault("imu_rate_hz", out["imu_samples"] / wall)
    out.setdefault("fps", out["frames"] / wall)
    out.update(
        wall_s=wall, cpu_s=cpu_used, cpu_fraction=cpu_used / wall, imu_produced=int(produced)
    )
    return out


def png_encode_ms(n: int = 10) -> float:
    """Why frames are logged raw: median time to PNG-encode one bench frame (level 1)."""
    import cv2

    from rigs.camera import open_camera

    cam = open_camera(CAM_URL.replace("realtime=1", "") + "&realtime=0")
    times = []
    for _ in range(n):
        image = cam.read().image
        t0 = time.perf_counter()
        cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        times.append((time.perf_counter() - t0) * 1e3)
    cam.close()
    return statistics.median(times)


def run_child(mode: str, duration_s: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run(
        [sys.executable, __file__, "--child", mode, "--duration", str(duration_s)],
        capture_output=True,
        text=True,
        env=env,
        timeout=duration_s * 10 + 120,
        check=True,
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--child", choices=("devices", "record"))
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.duration)))
        return
    runs: dict[str, list[dict]] = {"devices": [], "record": []}
    for _ in range(args.reps):  # interleaved, so that machine load hits both alike
        for mode in runs:
            runs[mode].append(run_child(mode, args.duration))
    report: dict = {
        "imu_url": IMU_URL,
        "camera_url": CAM_URL,
        "duration_s": args.duration,
        "reps": args.reps,
        "load_avg_1min": os.getloadavg()[0],
    }
    for mode, rs in runs.items():
        report[mode] = {
            "cpu_fraction_median": statistics.median(r["cpu_fraction"] for r in rs),
            "imu_rate_hz_median": statistics.median(r["imu_rate_hz"] for r in rs),
            "fps_median": statistics.median(r["fps"] for r in rs),
            "imu_dropped_total": sum(r["imu_dropped"] for r in rs),
            "imu_crc_errors_total": sum(r["imu_crc_errors"] for r in rs),
            "camera_dropped_total": sum(r["camera_dropped"] for r in rs),
            "runs": rs,
        }
    report["png_encode_ms_per_frame_median"] = png_encode_ms()
    base, rec = report["devices"], report["record"]
    report["recorder_cpu_overhead_fraction"] = (
        rec["cpu_fraction_median"] - base["cpu_fraction_median"]
    )
    report["record_over_devices_cpu_ratio"] = (
        rec["cpu_fraction_median"] / base["cpu_fraction_median"]
    )
    report["no_drops"] = rec["imu_dropped_total"] == 0 and rec["camera_dropped_total"] == 0
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
