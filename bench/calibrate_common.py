"""Shared by the calibration benchmarks: the simulator call, the targets and the errors of a
calibration against the simulator's truth."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.rotation import rotation_angle_deg
from calib.params import theta_from

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
