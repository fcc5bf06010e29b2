"""Kalibr's IMU file (``imu.yaml``, the ``--imu`` input of ``kalibr_calibrate_imu_camera``).

Keys: ``rostopic``, ``update_rate`` (Hz) and the four continuous-time noise parameters
``gyroscope_noise_density`` (rad/s/√Hz), ``gyroscope_random_walk`` (rad/s²/√Hz),
``accelerometer_noise_density`` (m/s²/√Hz), ``accelerometer_random_walk`` (m/s³/√Hz).

Where they come from, first match wins: the session's ``import.imu_noise`` (EuRoC's
``imu0/sensor.yaml``), the simulator's per-sample gyro noise in ``truth.yaml`` (density =
σ / √rate), else :data:`DEFAULT_NOISE`: the values of EuRoC's ADIS16448 ``sensor.yaml``, a
tactical-grade MEMS IMU; phone-class IMUs are noisier, and Kalibr's documentation recommends
measuring them (Allan variance) and inflating them. The file says which source was used.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, TypeGuard

import yaml

from blurtrack.io.yamlio import write_text_atomic

NOISE_KEYS = (
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
)
#: EuRoC MAV dataset, ``mav0/imu0/sensor.yaml`` (ADIS16448).
DEFAULT_NOISE = {
    "gyroscope_noise_density": 1.6968e-04,
    "gyroscope_random_walk": 1.9393e-05,
    "accelerometer_noise_density": 2.0000e-3,
    "accelerometer_random_walk": 3.0000e-3,
}


def imu_noise(session: Any) -> tuple[dict[str, float], str]:
    """The noise parameters of ``session`` and where they came from (see the module doc)."""
    noise = dict(DEFAULT_NOISE)
    given = ((session.meta.extra.get("import") or {}).get("imu_noise")) or {}
    found = {k: float(v) for k, v in given.items() if k in NOISE_KEYS and _ok(v)}
    if found:
        noise.update(found)
        return noise, f"session import.imu_noise ({', '.join(sorted(found))}); others defaults"
    if session.has_truth:
        g = ((session.truth or {}).get("simulator") or {}).get("gyro") or {}
        sigma = g.get("noise_radps")
        if _ok(sigma) and float(sigma) > 0:
            noise["gyroscope_noise_density"] = float(sigma) / math.sqrt(session.meta.imu.rate_hz)
            return noise, "simulator truth (gyro noise / sqrt(rate)); others defaults"
    return noise, "defaults (EuRoC ADIS16448 values; measure your IMU and replace them)"


def _ok(v: Any) -> TypeGuard[float]:
    return isinstance(v, (int, float)) and math.isfinite(float(v)) and 0.0 <= float(v) < 10.0


def kalibr_imu_dict(rate_hz: float, noise: dict[str, float], rostopic: str) -> dict[str, Any]:
    return {
        **{k: float(noise[k]) for k in NOISE_KEYS},
        "rostopic": rostopic,
        "update_rate": float(rate_hz),
    }


def write_kalibr_imu(session: Any, path: str | Path, rostopic: str = "/imu0") -> str:
    """Write ``imu.yaml`` for ``session``; returns the noise source."""
    noise, source = imu_noise(session)
    body = yaml.safe_dump(
        kalibr_imu_dict(session.meta.imu.rate_hz, noise, rostopic), sort_keys=False
    )
    write_text_atomic(path, f"# Kalibr IMU file; noise parameters from: {source}\n{body}")
    return source
