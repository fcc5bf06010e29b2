"""The calibration parameter vector and its mapping to and from :class:`Calibration`.

``theta`` (18,) = ``[timeshift_s, fx, fy, cx, cy, readout_s, bias_x, bias_y, bias_z,
rot_x, rot_y, rot_z, scale_xx, scale_yy, scale_zz, scale_xy, scale_xz, scale_yz]``: Kalibr time
shift (s, ``t_imu = t_cam + shift``), intrinsics (px), rolling-shutter readout (s), gyro bias
(rad/s, IMU frame), a rotation vector (rad) that perturbs the initial camera–IMU rotation on the
camera side, ``R_cam_imu = exp([rot]_x) · R_cam_imu_0``, and the symmetric gyro scale /
cross-axis error ``S`` of the measurement model ``ω_meas = (I + S) R_cam_imuᵀ ω_cam + bias``
(DESIGN: "scale and misalignment optional"; its antisymmetric part is a rotation, already
covered by ``rot``). ``S`` is optional (``--fit ...,scale``) and zero by default.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from blurtrack.calibration import Calibration
from blurtrack.rotation import so3_exp, so3_log
from calib.errors import CalibError

#: Scalar parameter names in ``theta`` order.
THETA_NAMES: tuple[str, ...] = (
    "timeshift_s", "fx", "fy", "cx", "cy", "readout_s",
    "bias_x", "bias_y", "bias_z", "rot_x", "rot_y", "rot_z",
    "scale_xx", "scale_yy", "scale_zz", "scale_xy", "scale_xz", "scale_yz",
)
N_THETA = len(THETA_NAMES)

#: ``--fit`` groups and the theta entries each selects.
GROUPS: dict[str, tuple[int, ...]] = {
    "timeshift": (0,), "fx": (1,), "fy": (2,), "cx": (3,), "cy": (4,), "readout": (5,),
    "bias": (6, 7, 8), "rotation": (9, 10, 11), "scale": (12, 13, 14, 15, 16, 17),
}
DEFAULT_FIT = "timeshift,fx,fy,cx,cy,readout,bias,rotation"

#: Typical magnitude of each parameter's uncertainty, used to scale steps and report units.
THETA_UNITS: dict[str, str] = {
    "timeshift_s": "s", "fx": "px", "fy": "px", "cx": "px", "cy": "px", "readout_s": "s",
    "bias_x": "rad/s", "bias_y": "rad/s", "bias_z": "rad/s",
    "rot_x": "rad", "rot_y": "rad", "rot_z": "rad",
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
    """The theta of a calibration, with a zero rotation perturbation."""
    cam = calib.camera
    return np.array([calib.timeshift_cam_imu_s, *cam.intrinsics, cam.readout_s,
                     *calib.gyro_bias_radps, *([0.0] * 9)], dtype=float)


def scale_matrix(theta: np.ndarray) -> np.ndarray:
    """``I + S`` (3, 3) of a theta (gyro scale and cross-axis error, IMU frame)."""
    sxx, syy, szz, sxy, sxz, syz = np.asarray(theta, float)[12:18]
    return np.eye(3) + np.array([[sxx, sxy, sxz], [sxy, syy, syz], [sxz, syz, szz]])


def apply_theta(base: Calibration, theta: np.ndarray) -> Calibration:
    """``base`` with the values of ``theta`` (rotation perturbation applied to its rotation).

    The gyro scale entries have no place in a :class:`Calibration`; see :func:`scale_matrix`.
    """
    th = np.asarray(theta, dtype=float)
    if th.shape != (N_THETA,) or not np.all(np.isfinite(th)):
        raise CalibError(f"parameter vector must be {N_THETA} finite numbers")
    if th[1] <= 0 or th[2] <= 0:
        raise CalibError(f"fit diverged: focal lengths {th[1]:.1f}, {th[2]:.1f} px")
    readout = float(th[5])
    if not 0.0 <= readout < 1.0:
        raise CalibError(f"fit diverged: readout {readout * 1e3:.3f} ms is outside [0, 1000) ms")
    R = so3_exp(th[9:12]) @ base.R_cam_imu
    return base.with_(intrinsics=tuple(float(v) for v in th[1:5]), readout_s=readout,
                      timeshift_cam_imu_s=float(th[0]), gyro_bias_radps=th[6:9].copy(),
                      R_cam_imu=R)


def rotation_error_rad(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of ``R_a R_b^T`` (camera-side difference)."""
    return so3_log(np.asarray(R_a) @ np.asarray(R_b).T)
