"""The calibration parameter vector and its mapping to and from :class:`Calibration`.

``theta`` (18,) = ``[timeshift_s, fx, fy, cx, cy, readout_s, bias_x, bias_y, bias_z,
rot_x, rot_y, rot_z, scale_xx, scale_yy, scale_zz, scale_xy, scale_xz, scale_yz]``: Kalibr time
shift (s, ``t_imu = t_cam + shift``), intrinsics (px), rolling-shutter readout (s), gyro bias
(rad/s, IMU frame), a rotation vector (rad) that perturbs the initial camera–IMU rotation on the
camera side, ``R_cam_imu = exp([rot]_x) · R_cam_imu_0``, and the symmetric gyro scale /
cross-axis error ``S`` of the measurement model ``ω_meas = (I + S) R_cam_imuᵀ ω_cam + bias``
(DESIGN: "scale and misalignment optional"; its antisymmetric part is a rotation, already
covered by ``rot``). ``I + S`` is the calibration's ``gyro_scale_matrix``, which the blur model
(:class:`blurtrack.geometry.blur_model.BlurModel`) applies everywhere, so ``S`` is fitted by
default.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.rotation import so3_exp, so3_log
from calib.errors import CalibError

#: Scalar parameter names in ``theta`` order.
THETA_NAMES: tuple[str, ...] = (
    "timeshift_s",
    "fx",
    "fy",
    "cx",
    "cy",
    "readout_s",
    "bias_x",
    "bias_y",
    "bias_z",
    "rot_x",
    "rot_y",
    "rot_z",
    "scale_xx",
    "scale_yy",
    "scale_zz",
    "scale_xy",
    "scale_xz",
    "scale_yz",
)
N_THETA = len(THETA_NAMES)

#: Largest plausible gyro scale / cross-axis error (MEMS datasheets: a few percent at most).
MAX_SCALE_ERROR = 0.1

#: The named layout of ``theta``: every scalar by its name, and the blocks. Modules address
#: theta only through it (``theta[LAYOUT["bias"]]``), never by bare indices.
LAYOUT: dict[str, Any] = {
    **{name: i for i, name in enumerate(THETA_NAMES)},
    "focal": slice(1, 3),
    "intrinsics": slice(1, 5),
    "bias": slice(6, 9),
    "rotation": slice(9, 12),
    "scale": slice(12, 18),
}
#: ``scale`` entries in ``theta`` order: (row, column) of ``S`` (symmetric).
SCALE_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


@dataclass(frozen=True)
class Bound:
    """Admissible range of one parameter and what a solver step past it does: ``project``
    (clip onto the bound: a duration at 0 must be reachable) or ``reject`` (the step is
    refused and the damping raised)."""

    lo: float
    hi: float
    policy: str

    def __post_init__(self) -> None:
        if self.policy not in ("project", "reject") or not self.lo < self.hi:
            raise ValueError(f"invalid bound {self}")


#: Bounds table of the solver (every parameter not listed is unbounded). The readout is a
#: duration in [0, 1) s: rejecting steps below 0 stalled global-shutter fits at their start
#: (noise pulls every Gauss–Newton step below 0), so it is projected. Focal lengths must be
#: positive. A gyro scale error beyond :data:`MAX_SCALE_ERROR` is implausible (and
#: :func:`apply_theta` calls it divergence): steps there are refused, so a weakly determined
#: scale (motion without roll) stays in range.
BOUNDS: dict[str, Bound] = {
    "fx": Bound(0.0, math.inf, "reject"),
    "fy": Bound(0.0, math.inf, "reject"),
    "readout_s": Bound(0.0, 0.999, "project"),
    **{
        f"scale_{a}": Bound(-MAX_SCALE_ERROR, MAX_SCALE_ERROR, "reject")
        for a in ("xx", "yy", "zz", "xy", "xz", "yz")
    },
}


def bounded_step(theta: np.ndarray) -> np.ndarray | None:
    """``theta`` with projected bounds applied, or ``None`` when a ``reject`` bound is broken
    (strictly inside for ``reject``, closed for ``project``)."""
    out = np.asarray(theta, float).copy()
    for name, b in BOUNDS.items():
        i = LAYOUT[name]
        if b.policy == "project":
            out[i] = min(max(out[i], b.lo), b.hi)
        elif not b.lo < out[i] < b.hi:
            return None
    return out


def scale_tuple(theta: Sequence[Any] | np.ndarray | Any) -> tuple[Any, ...]:
    """``I + S`` of a theta as a row-major 9-tuple (numbers or CasADi scalars)."""
    sxx, syy, szz, sxy, sxz, syz = (theta[i] for i in range(*LAYOUT["scale"].indices(N_THETA)))
    return (1 + sxx, sxy, sxz, sxy, 1 + syy, syz, sxz, syz, 1 + szz)


def inverse3(M: Sequence[Any]) -> tuple:
    """Exact inverse of a 3×3 matrix given as a row-major 9-tuple (adjugate over the
    determinant; numbers, arrays or CasADi scalars). The gyro scale's ``(I + S)⁻¹`` in both
    backends, as :class:`blurtrack.geometry.blur_model.BlurModel` applies it.

    >>> bool(np.allclose(np.reshape(inverse3((2, 0, 0, 0, 4, 0, 0, 1, 1)), (3, 3)),
    ...                  np.linalg.inv([[2, 0, 0], [0, 4, 0], [0, 1, 1]])))
    True
    """
    a, b, c, d, e, f, g, h, i = M
    co = (e * i - f * h, c * h - b * i, b * f - c * e)
    det = a * co[0] + d * co[1] + g * co[2]
    adj = (
        *co,
        f * g - d * i,
        a * i - c * g,
        c * d - a * f,
        d * h - e * g,
        b * g - a * h,
        a * e - b * d,
    )
    return tuple(x / det for x in adj)


#: ``--fit`` groups and the theta entries each selects.
GROUPS: dict[str, tuple[int, ...]] = {
    "timeshift": (LAYOUT["timeshift_s"],),
    "fx": (LAYOUT["fx"],),
    "fy": (LAYOUT["fy"],),
    "cx": (LAYOUT["cx"],),
    "cy": (LAYOUT["cy"],),
    "readout": (LAYOUT["readout_s"],),
    **{g: tuple(range(N_THETA))[LAYOUT[g]] for g in ("bias", "rotation", "scale")},
}
#: Every group. ``scale`` is in: ``gyro_scale_matrix`` is part of the calibration file and the
#: blur model, and an unmodelled scale error biases the focal lengths (docs/calibration.md).
DEFAULT_FIT = "timeshift,fx,fy,cx,cy,readout,bias,rotation,scale"


#: Typical magnitude of each parameter's uncertainty, used to scale steps and report units.
THETA_UNITS: dict[str, str] = {
    "timeshift_s": "s",
    "fx": "px",
    "fy": "px",
    "cx": "px",
    "cy": "px",
    "readout_s": "s",
    "bias_x": "rad/s",
    "bias_y": "rad/s",
    "bias_z": "rad/s",
    "rot_x": "rad",
    "rot_y": "rad",
    "rot_z": "rad",
    **{f"scale_{a}": "1" for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
}


def parse_fit(spec: str | Sequence[str]) -> tuple[int, ...]:
    """Sorted theta indices of a ``--fit`` list such as ``"timeshift,fx,fy"``.

    >>> parse_fit("fx,timeshift")
    (0, 1)
    """
    names = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    names = [n for n in names if n]
    if not names:
        raise CalibError("--fit selects no parameter")
    bad = [n for n in names if n not in GROUPS]
    if bad:
        raise CalibError(f"--fit: unknown parameter(s) {bad}; choose from {sorted(GROUPS)}")
    return tuple(sorted({i for n in names for i in GROUPS[n]}))


def theta_from(calib: Calibration) -> np.ndarray:
    """The theta of a calibration, with a zero rotation perturbation.

    The scale entries are the symmetric part of ``gyro_scale_matrix - I``; an antisymmetric
    part (a rotation of the gyro axes) is not representable here: move it into the mounting
    rotation first with :func:`symmetric_scale_form`.
    """
    cam = calib.camera
    th = np.zeros(N_THETA)
    th[LAYOUT["timeshift_s"]] = calib.timeshift_cam_imu_s
    th[LAYOUT["intrinsics"]] = cam.intrinsics
    th[LAYOUT["readout_s"]] = cam.readout_s
    th[LAYOUT["bias"]] = calib.gyro_bias_radps
    th[LAYOUT["scale"]] = scale_entries(calib.gyro_scale_matrix)
    return th


def scale_entries(M: np.ndarray) -> np.ndarray:
    """``(6,)`` theta scale entries of the symmetric part of ``M - I``."""
    M = np.asarray(M, dtype=float).reshape(3, 3)
    S = (M + M.T) / 2 - np.eye(3)
    return np.array([S[r, c] for r, c in SCALE_ENTRIES])


def symmetric_scale_form(calib: Calibration) -> Calibration:
    """The same measurement model with a symmetric ``gyro_scale_matrix``.

    ``M = P Q`` (polar decomposition, ``P`` symmetric positive definite, ``Q`` a rotation) gives
    ``M R_cam_imuᵀ = P (R_cam_imu Qᵀ)ᵀ``: the rotation factor of ``M`` is a rotation of the
    gyro's axes, indistinguishable from the mounting rotation, and moves into it.

    >>> from blurtrack.geometry.camera import Camera
    >>> c = Calibration(Camera((64, 48), (50.0, 50.0, 32.0, 24.0)),
    ...                 gyro_scale_matrix=so3_exp(np.array([0.0, 0.0, 0.01])) * 1.002)
    >>> n = symmetric_scale_form(c)
    >>> bool(np.allclose(n.gyro_scale_matrix, np.eye(3) * 1.002))
    True
    >>> bool(np.allclose(n.gyro_scale_matrix @ n.R_cam_imu.T, c.gyro_scale_matrix @ c.R_cam_imu.T))
    True
    """
    M = np.asarray(calib.gyro_scale_matrix, dtype=float)
    if np.array_equal(M, M.T):
        return calib
    U, s, Vt = np.linalg.svd(M)
    Q = U @ Vt
    P = U @ np.diag(s) @ U.T
    return calib.with_(gyro_scale_matrix=(P + P.T) / 2, R_cam_imu=calib.R_cam_imu @ Q.T)


def scale_matrix(theta: np.ndarray) -> np.ndarray:
    """``I + S`` (3, 3) of a theta (gyro scale and cross-axis error, IMU frame)."""
    return np.array(scale_tuple(np.asarray(theta, float)), dtype=float).reshape(3, 3)


def apply_theta(base: Calibration, theta: np.ndarray) -> Calibration:
    """``base`` with the values of ``theta`` (rotation perturbation applied to its rotation,
    ``gyro_scale_matrix = I + S``)."""
    th = np.asarray(theta, dtype=float)
    if th.shape != (N_THETA,) or not np.all(np.isfinite(th)):
        raise CalibError(f"parameter vector must be {N_THETA} finite numbers")
    fx, fy = th[LAYOUT["focal"]]
    if fx <= 0 or fy <= 0:
        raise CalibError(f"fit diverged: focal lengths {fx:.1f}, {fy:.1f} px")
    readout = float(th[LAYOUT["readout_s"]])
    if not 0.0 <= readout < 1.0:
        raise CalibError(f"fit diverged: readout {readout * 1e3:.3f} ms is outside [0, 1000) ms")
    S = scale_matrix(th) - np.eye(3)
    if np.max(np.abs(S)) > MAX_SCALE_ERROR:
        raise CalibError(
            f"fit diverged: gyro scale/cross-axis error of "
            f"{np.max(np.abs(S)) * 100:.0f} % (the data contradict the model)"
        )
    R = so3_exp(th[LAYOUT["rotation"]]) @ base.R_cam_imu
    return base.with_(
        intrinsics=tuple(float(v) for v in th[LAYOUT["intrinsics"]]),
        readout_s=readout,
        timeshift_cam_imu_s=float(th[LAYOUT["timeshift_s"]]),
        gyro_bias_radps=th[LAYOUT["bias"]].copy(),
        R_cam_imu=R,
        gyro_scale_matrix=scale_matrix(th),
    )


def rotation_error_rad(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of ``R_a R_b^T`` (camera-side difference)."""
    return so3_log(np.asarray(R_a) @ np.asarray(R_b).T)
