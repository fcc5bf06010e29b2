"""Calibration error for robustness studies: heat maps from a perturbed model.

The blur of a triplet always comes from the true calibration and gyro; with a
:class:`Perturbation` its heat maps come from a model whose calibration and gyro samples carry
errors drawn per triplet (1-sigma values given here), so a network trained or tested on such
data shows how sensitive it is to calibration error. Drawn errors go to the manifest.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace

#: Keys accepted by :meth:`Perturbation.parse` and their units.
KEYS = {
    "timeshift_ms": "ms",
    "gyro_noise": "rad/s per sample",
    "gyro_bias": "rad/s per axis",
    "focal_rel": "relative",
    "principal_px": "px",
    "readout_rel": "relative",
}


@dataclass(frozen=True)
class Perturbation:
    """1-sigma errors of the model used for heat maps (all zero: the true model)."""

    timeshift_ms: float = 0.0
    gyro_noise: float = 0.0
    gyro_bias: float = 0.0
    focal_rel: float = 0.0
    principal_px: float = 0.0
    readout_rel: float = 0.0

    def __post_init__(self) -> None:
        for k in KEYS:
            v = float(getattr(self, k))
            if not (math.isfinite(v) and v >= 0):
                raise SynthesisError(f"perturbation {k} must be a finite sigma >= 0, got {v}")
            object.__setattr__(self, k, v)
        if self.focal_rel >= 0.2 or self.readout_rel >= 0.5:
            raise SynthesisError("perturbation focal_rel must be < 0.2 and readout_rel < 0.5")

    @property
    def active(self) -> bool:
        return any(getattr(self, k) > 0 for k in KEYS)

    @property
    def margin_s(self) -> float:
        """Extra gyro coverage a perturbed time shift may need (6 sigma)."""
        return 6e-3 * self.timeshift_ms

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def parse(cls, text: str) -> Perturbation:
        """From ``"timeshift_ms=2,gyro_noise=0.01"`` (keys: :data:`KEYS`).

        >>> Perturbation.parse("timeshift_ms=2, focal_rel=0.01").timeshift_ms
        2.0
        """
        values: dict[str, float] = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            key, sep, val = part.partition("=")
            key = key.strip()
            if not sep or key not in KEYS:
                raise SynthesisError(
                    f"bad perturbation item {part!r}; use KEY=SIGMA with KEY in {', '.join(KEYS)}"
                )
            try:
                values[key] = float(val)
            except ValueError:
                raise SynthesisError(f"perturbation {key}: {val!r} is not a number") from None
        return cls(**values)

    def apply(
        self, calib: Calibration, trace: GyroTrace, rng: np.random.Generator
    ) -> tuple[Calibration, GyroTrace, dict[str, Any]]:
        """A perturbed copy of ``calib`` and ``trace`` and the errors drawn."""
        dt = float(rng.normal(0.0, self.timeshift_ms * 1e-3)) if self.timeshift_ms else 0.0
        bias = rng.normal(0.0, self.gyro_bias, 3) if self.gyro_bias else np.zeros(3)
        fscale = 1.0 + (float(rng.normal(0.0, self.focal_rel)) if self.focal_rel else 0.0)
        dpp = rng.normal(0.0, self.principal_px, 2) if self.principal_px else np.zeros(2)
        rscale = 1.0 + (float(rng.normal(0.0, self.readout_rel)) if self.readout_rel else 0.0)
        cam = calib.camera
        fx, fy, cx, cy = cam.intrinsics
        cam_p = replace(
            cam,
            intrinsics=(fx * fscale, fy * fscale, cx + dpp[0], cy + dpp[1]),
            readout_s=min(cam.readout_s * max(rscale, 0.0), 0.999),
        )
        # A model that believes the bias is b - e sees ω_meas - b + e: the true rate plus e.
        calib_p = replace(
            calib,
            camera=cam_p,
            timeshift_cam_imu_s=calib.timeshift_cam_imu_s + dt,
            gyro_bias_radps=calib.gyro_bias_radps - bias,
        )
        omega = trace.omega_radps
        if self.gyro_noise:
            omega = omega + rng.normal(0.0, self.gyro_noise, omega.shape)
        drawn = {
            "timeshift_s": dt,
            "gyro_bias_radps": bias.tolist(),
            "focal_scale": fscale,
            "principal_px": dpp.tolist(),
            "readout_scale": rscale,
        }
        return calib_p, GyroTrace(trace.t_s, omega, trace.max_gap_s), drawn
