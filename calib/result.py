"""Result objects of a calibration: endpoint-error statistics and the fit result."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.io.calibration import calibration_to_dict
from calib.params import THETA_NAMES


@dataclass(frozen=True)
class ErrorStats:
    """Endpoint-error statistics (pixels) of a set of streaks."""

    n: int
    mean_px: float
    median_px: float
    p95_px: float
    rms_px: float
    max_px: float

    @classmethod
    def of(cls, errors_px: np.ndarray) -> ErrorStats:
        e = np.asarray(errors_px, float).reshape(-1)
        if e.size == 0:
            nan = float("nan")
            return cls(0, nan, nan, nan, nan, nan)
        return cls(
            int(e.size),
            float(e.mean()),
            float(np.median(e)),
            float(np.percentile(e, 95)),
            float(np.sqrt(np.mean(e**2))),
            float(e.max()),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "n": self.n,
            "mean_px": self.mean_px,
            "median_px": self.median_px,
            "p95_px": self.p95_px,
            "rms_px": self.rms_px,
            "max_px": self.max_px,
        }


@dataclass(frozen=True)
class CalibResult:
    """Outcome of :func:`calib.fit.calibrate`.

    ``status`` is ``ok`` (converged, no warning), ``warning`` (converged with warnings) or
    ``failed`` (the data contradict the model or the fit did not converge; ``warnings`` say why).
    ``values``/``sigma`` are keyed by :data:`calib.params.THETA_NAMES` (estimated ones only in
    ``sigma``); rotation entries are the rotation vector (rad) applied to the initial rotation.
    """

    status: str
    calibration: Calibration
    initial: Calibration
    values: dict[str, float]
    sigma: dict[str, float]
    correlation: dict[str, dict[str, float]]
    fitted: tuple[str, ...]
    fixed_unobservable: tuple[str, ...]
    iterations: int
    converged: bool
    train: ErrorStats
    train_all: ErrorStats
    holdout: ErrorStats
    holdout_all: ErrorStats
    n_outliers: int
    n_flipped: int
    residual_sigma_px: float
    init_shift_curve: tuple[tuple[float, float], ...]
    warnings: tuple[str, ...]
    timings_s: dict[str, float] = field(default_factory=dict)
    #: What the final stage fitted (``endpoints``, ``tracks`` or ``both``) and, with tracks,
    #: the inter-frame tracks' errors (inliers) and counts.
    residuals: str = "endpoints"
    tracks: ErrorStats | None = None
    n_tracks: int = 0
    n_track_outliers: int = 0
    #: The values of the training-frames fit that the hold-out statistics evaluate, when the
    #: result is the refit on every frame (:func:`calib.fit.calibrate`); ``None`` otherwise.
    holdout_fit_values: dict[str, float] | None = None

    def __post_init__(self) -> None:
        if self.status not in ("ok", "warning", "failed"):
            raise ValueError(f"status must be ok, warning or failed, got {self.status!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "converged": self.converged,
            "iterations": self.iterations,
            "fitted": list(self.fitted),
            "fixed_unobservable": list(self.fixed_unobservable),
            "values": dict(self.values),
            "sigma": dict(self.sigma),
            "correlation": self.correlation,
            "train_inliers": self.train.to_dict(),
            "train_all": self.train_all.to_dict(),
            "holdout_inliers": self.holdout.to_dict(),
            "holdout_all": self.holdout_all.to_dict(),
            "n_outliers": self.n_outliers,
            "n_flipped": self.n_flipped,
            "residual_sigma_px": self.residual_sigma_px,
            "residuals": self.residuals,
            "n_tracks": self.n_tracks,
            "n_track_outliers": self.n_track_outliers,
            "tracks_inliers": None if self.tracks is None else self.tracks.to_dict(),
            "refitted_on_all_frames": self.holdout_fit_values is not None,
            "holdout_fit_values": self.holdout_fit_values,
            "warnings": list(self.warnings),
            "timings_s": dict(self.timings_s),
            "calibration": calibration_to_dict(self.calibration),
        }


def sigma_block(sigma: dict[str, float]) -> dict[str, Any]:
    """The calibration file's ``sigma`` entry (DESIGN keys; ``null`` where not estimated)."""

    def get(name: str) -> float | None:
        return float(sigma[name]) if name in sigma else None

    out: dict[str, Any] = {}
    if "timeshift_s" in sigma:
        out["timeshift_cam_imu"] = get("timeshift_s")
    if any(k in sigma for k in ("fx", "fy", "cx", "cy")):
        out["intrinsics"] = [get(k) for k in ("fx", "fy", "cx", "cy")]
    if "readout_s" in sigma:
        out["readout_s"] = get("readout_s")
    if any(k.startswith("bias") for k in sigma):
        out["gyro_bias_radps"] = [get(k) for k in ("bias_x", "bias_y", "bias_z")]
    if any(k.startswith("rot") for k in sigma):
        out["R_cam_imu_rotvec_rad"] = [get(k) for k in ("rot_x", "rot_y", "rot_z")]
    if any(k.startswith("scale") for k in sigma):
        out["gyro_scale"] = [get(f"scale_{a}") for a in ("xx", "yy", "zz", "xy", "xz", "yz")]
    return out


def named(values: np.ndarray, idx: tuple[int, ...] | None = None) -> dict[str, float]:
    ids = range(len(THETA_NAMES)) if idx is None else idx
    vals = np.asarray(values, float)
    if idx is None:
        return {THETA_NAMES[i]: float(vals[i]) for i in ids}
    return {THETA_NAMES[i]: float(v) for i, v in zip(ids, vals, strict=True)}
