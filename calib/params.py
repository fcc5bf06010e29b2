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

from collections.abc import Sequence

import numpy as np

from blurtrack.geometry.rotation import so3_exp, so3_log
from blurtrack.io.calibration import Calibration
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

#: ``--fit`` groups and the theta entries each selects.
GROUPS: dict[str, tuple[int, ...]] = {
    "timeshift": (0,),
    "fx": (1,),
    "fy": (2,),
    "cx": (3,),
    "cy": (4,),
    "readout": (5,),
    "bias": (6, 7, 8),
    "rotation": (9, 10, 11),
    "scale": (12, 13, 14, 15, 16, 17),
}
#: Every group. ``scale`` is in: ``gyro_scale_matrix`` is part of the calibration file and the
#: blur model, and an unmodelled scale error biases the focal lengths (docs/calibration.md).
DEFAULT_FIT = "timeshift,fx,fy,cx,cy,readout,bias,rotation,scale"

#: Largest plausible gyro scale / cross-axis error (MEMS datasheets: a few percent at most).
MAX_SCALE_ERROR = 0.1

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
    M = np.asarray(calib.gyro_scale_matrix, dtype=float)
    S = (M + M.T) / 2 - np.eye(3)
    return np.array(
        [
            calib.timeshift_cam_imu_s,
            *cam.intrinsics,
            cam.readout_s,
            *calib.gyro_bias_radps,
            0.0,
            0.0,
            0.0,
            S[0, 0],
            S[1, 1],
            S[2, 2],
            S[0, 1],
            S[0, 2],
            S[1, 2],
        ],
        dtype=float,
    )


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
    sxx, syy, szz, sxy, sxz, syz = np.asarray(theta, float)[12:18]
    return np.eye(3) + np.array([[sxx, sxy, sxz], [sxy, syy, syz], [sxz, syz, szz]])


def apply_theta(base: Calibration, theta: np.ndarray) -> Calibration:
    """``base`` with the values of ``theta`` (rotation perturbation applied to its rotation,
    ``gyro_scale_matrix = I + S``)."""
    th = np.asarray(theta, dtype=float)
    if th.shape != (N_THETA,) or not np.all(np.isfinite(th)):
        raise CalibError(f"parameter vector must be {N_THETA} finite numbers")
    if th[1] <= 0 or th[2] <= 0:
        raise CalibError(f"fit diverged: focal lengths {th[1]:.1f}, {th[2]:.1f} px")
    readout = float(th[5])
    if not 0.0 <= readout < 1.0:
        raise CalibError(f"fit diverged: readout {readout * 1e3:.3f} ms is outside [0, 1000) ms")
    S = scale_matrix(th) - np.eye(3)
    if np.max(np.abs(S)) > MAX_SCALE_ERROR:
        raise CalibError(
            f"fit diverged: gyro scale/cross-axis error of "
            f"{np.max(np.abs(S)) * 100:.0f} % (the data contradict the model)"
        )
    R = so3_exp(th[9:12]) @ base.R_cam_imu
    return base.with_(
        intrinsics=tuple(float(v) for v in th[1:5]),
        readout_s=readout,
        timeshift_cam_imu_s=float(th[0]),
        gyro_bias_radps=th[6:9].copy(),
        R_cam_imu=R,
        gyro_scale_matrix=scale_matrix(th),
    )


def rotation_error_rad(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of ``R_a R_b^T`` (camera-side difference)."""
    return so3_log(np.asarray(R_a) @ np.asarray(R_b).T)
