"""Write a simulated recording as a session folder with its truth.yaml."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.io.session import SessionWriter
from rigs.sim.rig import SimRig
from rigs.sim.truthio import write_truth

TRUTH_FORMAT = "blurtrack-truth/1"


def write_session(
    rig: SimRig, out: str | Path, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """Render every frame of ``rig`` into the session folder ``out`` (must be new or empty).

    Gyro samples go in first, then each frame as it is rendered, then ``truth.yaml``. Returns a
    summary (counts, streak lengths, saturation, the true offset and readout, timings).
    """
    t0 = time.perf_counter()
    frames: list[dict[str, Any]] = []
    lengths: list[float] = []
    inside = saturated = 0
    top = (1 << rig.preset.bit_depth) - 1
    t_imu_ns = rig.gyro_times_ns()
    with SessionWriter(out, rig.nominal_meta()) as w:
        w.add_imu(t_imu_ns, rig.sample_gyro(t_imu_ns * 1e-9))
        render_s = 0.0
        for i, ts_ns in enumerate(rig.frame_times_ns):
            tr = time.perf_counter()
            img = rig.render_frame(int(ts_ns) * 1e-9)
            render_s += time.perf_counter() - tr
            w.add_frame(int(ts_ns), img, rig.exposure_ns)
            fr = rig.frame_truth(i)
            frames.append(fr)
            lengths.extend(s["length_px"] for s in fr["streaks"])
            inside += sum(s["inside"] for s in fr["streaks"])
            saturated += int(np.count_nonzero(img >= top))
            if progress is not None:
                progress(i + 1, rig.n_frames)
        truth = {
            "format": TRUTH_FORMAT,
            "calibration": rig.calibration.to_dict(),
            "simulator": rig.simulator_info(),
            "frames": frames,
        }
        tt = time.perf_counter()
        write_truth(Path(out) / "truth.yaml", truth)
        truth_s = time.perf_counter() - tt
    cam = rig.camera
    n_px = rig.n_frames * cam.width * cam.height
    return {
        "session": str(out),
        "preset": rig.preset.name,
        "seed": rig.seed,
        "frames": rig.n_frames,
        "imu_samples": int(t_imu_ns.size),
        "resolution": list(cam.resolution),
        "exposure_s": rig.preset.exposure_s,
        "streaks": len(lengths),
        "streaks_inside": int(inside),
        "streak_length_px": {
            "median": float(np.median(lengths)) if lengths else 0.0,
            "max": float(np.max(lengths)) if lengths else 0.0,
        },
        "saturated_fraction": saturated / n_px,
        "true": {
            "intrinsics": list(cam.intrinsics),
            "readout_s": cam.readout_s,
            "timeshift_cam_imu_s": rig.calibration.timeshift_cam_imu_s,
            "misalignment_deg": rig.misalignment_deg,
        },
        "motion": rig.motion_info,
        "seconds": {"total": time.perf_counter() - t0, "render": render_s, "truth": truth_s},
    }
