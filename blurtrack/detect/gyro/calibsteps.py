"""The calibration parameters of the session's fit (:mod:`blurtrack.detect.gyro.sessioncalib`):
their names and finite-difference steps, the models moved by one step each (the columns of the
prediction's Jacobian), the model a fitted error ``d`` corrects, and the change between two
calibrations by name.

``d`` is in steps of :data:`CALIBRATION_STEPS`, in the order of :data:`PARAMETERS`: focal
length, principal point, ``R_cam_imu``'s three angles, time offset, readout, gyro bias, and the
gyro's scale and cross-axis terms (:data:`SCALE_TERMS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from blurtrack.geometry.rotation import so3_log

#: The calibration parameters of the session's fit and the step of each finite difference:
#: focal length (relative), principal point (px), ``R_cam_imu`` (rad about each axis), time
#: offset and readout (s), gyro bias (rad/s about each axis), gyro scale and cross-axis terms
#: (relative: :data:`SCALE_TERMS`). Each step moves a dot ~1-10 px over an exposure (f ~1000
#: px, rates ~1 rad/s, 10-50 ms): far above the predictions' rounding, and where the
#: prediction is still linear (its curvature costs ~step^2).
CALIBRATION_STEPS = {
    "focal": 0.01,
    "pp": 5.0,
    "axes": 0.01,
    "time": 1e-3,
    "bias": 0.01,
    "scale": 0.01,
}
#: The gyro scale matrix's fitted terms ``(i, j)`` (IMU axes): ``M`` moves to ``(I + e S) M``,
#: ``S`` symmetric with ones at ``(i, j)`` and ``(j, i)``. A MEMS gyro's scale factors and
#: cross-axis sensitivities are each off by up to a few per cent, which on a streak of 100 px
#: is 1-3 px: the vectors of fast frames, all wrong the same way, that the other parameters
#: cannot explain (``hard`` seed 12: the true symmetric ``M`` in the initial calibration lifts
#: the ``quality_ok`` coverage from 59.2 to 64.1 %, its diagonal alone to 59.5 %).
SCALE_TERMS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
#: Parameter names of ``d``, in the order of the Jacobian's columns.
PARAMETERS = (
    "focal_rel",
    "cx_px",
    "cy_px",
    "axis_x_rad",
    "axis_y_rad",
    "axis_z_rad",
    "timeshift_s",
    "readout_s",
    "bias_x_radps",
    "bias_y_radps",
    "bias_z_radps",
    *(f"scale_{'xyz'[i]}{'xyz'[j]}" for i, j in SCALE_TERMS),
)


def _rotation(v: np.ndarray) -> np.ndarray:
    """The rotation matrix of rotation vector ``v`` (rad)."""
    th = float(np.linalg.norm(v))
    if th == 0.0:
        return np.eye(3)
    a = v / th
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.asarray(np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K)


def _scale_term(i: int, j: int) -> np.ndarray:
    """``S`` of the scale term ``(i, j)`` (:data:`SCALE_TERMS`): symmetric, ones at ``(i, j)``
    and ``(j, i)``."""
    S = np.zeros((3, 3))
    S[i, j] = S[j, i] = 1.0
    return S


def _scaled(M: np.ndarray, e: Sequence[float] | np.ndarray) -> np.ndarray:
    """The gyro scale matrix ``M`` moved by the scale terms ``e`` (:data:`SCALE_TERMS` order,
    in steps of ``CALIBRATION_STEPS["scale"]``): ``(I + sum e_k S_k step) M``."""
    S = sum(
        (float(v) * _scale_term(i, j) for v, (i, j) in zip(e, SCALE_TERMS, strict=True)),
        np.zeros((3, 3)),
    )
    return np.asarray((np.eye(3) + CALIBRATION_STEPS["scale"] * S) @ M)


def perturbed_models(model: Any) -> list[Any]:
    """``model`` with each calibration parameter of :data:`CALIBRATION_STEPS` moved by its
    step, in the order of :data:`PARAMETERS` (the columns of the prediction's Jacobian)."""
    c = model.calib
    fx, fy, cx, cy = c.camera.intrinsics
    bias = np.asarray(c.gyro_bias_radps, float)
    M = np.asarray(c.gyro_scale_matrix, float)
    fs, pp, ang, dt, rate = (CALIBRATION_STEPS[k] for k in ("focal", "pp", "axes", "time", "bias"))
    calibs = [
        c.with_(intrinsics=(fx * (1.0 + fs), fy * (1.0 + fs), cx, cy)),
        c.with_(intrinsics=(fx, fy, cx + pp, cy)),
        c.with_(intrinsics=(fx, fy, cx, cy + pp)),
        *(c.with_(R_cam_imu=_rotation(ang * ax) @ c.R_cam_imu) for ax in np.eye(3)),
        c.with_(timeshift_cam_imu_s=c.timeshift_cam_imu_s + dt),
        c.with_(readout_s=c.camera.readout_s + dt),
        *(c.with_(gyro_bias_radps=bias + rate * ax) for ax in np.eye(3)),
        *(c.with_(gyro_scale_matrix=_scaled(M, e)) for e in np.eye(len(SCALE_TERMS))),
    ]
    # The model's gyro is already resampled: no second resampling.
    return [replace(model, calib=k, gyro_upsample=1) for k in calibs]


def corrected_model(model: Any, d: np.ndarray) -> Any:
    """``model`` with the calibration error ``d (17,)`` of :func:`session_residual` applied (in
    :data:`CALIBRATION_STEPS` units, the order of :func:`perturbed_models`: ``d = e_i`` is the
    ``i``-th perturbed model; the readout no less than 0)."""
    c = model.calib
    fx, fy, cx, cy = c.camera.intrinsics
    bias = np.asarray(c.gyro_bias_radps, float)
    fs, pp, ang, dt, rate = (CALIBRATION_STEPS[k] for k in ("focal", "pp", "axes", "time", "bias"))
    e = [float(v) for v in d]  # python floats, as the perturbed models' parameters
    turn = ang * np.asarray(e[3:6])
    M = np.asarray(c.gyro_scale_matrix, float)
    calib = c.with_(
        intrinsics=(fx * (1.0 + fs * e[0]), fy * (1.0 + fs * e[0]), cx + pp * e[1], cy + pp * e[2]),
        R_cam_imu=_rotation(turn) @ c.R_cam_imu if np.any(turn) else c.R_cam_imu,
        timeshift_cam_imu_s=c.timeshift_cam_imu_s + dt * e[6],
        readout_s=max(c.camera.readout_s + dt * e[7], 0.0),
        gyro_bias_radps=bias + rate * np.asarray(e[8:11]) if any(e[8:11]) else c.gyro_bias_radps,
        gyro_scale_matrix=_scaled(M, e[11:]) if any(e[11:]) else M,
    )
    return replace(model, calib=calib, gyro_upsample=1)


def difference(before: Any, after: Any) -> dict[str, float]:
    """``after`` less ``before`` by parameter name (:data:`PARAMETERS`, units in the names;
    the axes as the rotation vector of ``R_after R_before^T``; the gyro scale terms as the
    symmetric part of ``M_after M_before^-1 - I``)."""
    f0, _, cx0, cy0 = before.camera.intrinsics
    f1, _, cx1, cy1 = after.camera.intrinsics
    rotvec = so3_log(np.asarray(after.R_cam_imu) @ np.asarray(before.R_cam_imu).T)
    bias = np.asarray(after.gyro_bias_radps, float) - np.asarray(before.gyro_bias_radps, float)
    # (I + S) = M_after M_before^-1: S's symmetric part, by term (the off-diagonal ones: the
    # mean of the pair, as ``S`` of a term has both)
    S = np.asarray(after.gyro_scale_matrix, float) @ np.linalg.inv(
        np.asarray(before.gyro_scale_matrix, float)
    ) - np.eye(3)
    S = 0.5 * (S + S.T)
    values = [
        f1 / f0 - 1.0,
        cx1 - cx0,
        cy1 - cy0,
        *rotvec.tolist(),
        after.timeshift_cam_imu_s - before.timeshift_cam_imu_s,
        after.camera.readout_s - before.camera.readout_s,
        *bias.tolist(),
        *(float(S[i, j]) for i, j in SCALE_TERMS),
    ]
    return {k: float(v) for k, v in zip(PARAMETERS, values, strict=True)}


def largest_step(change: dict[str, float]) -> float:
    """The largest move of :func:`difference`'s ``change`` in units of its parameter's step
    (:data:`CALIBRATION_STEPS`)."""
    step = {"focal_rel": "focal", "cx_px": "pp", "cy_px": "pp", "timeshift_s": "time"}
    step |= {"readout_s": "time"}
    step |= {k: "axes" for k in ("axis_x_rad", "axis_y_rad", "axis_z_rad")}
    step |= {k: "bias" for k in ("bias_x_radps", "bias_y_radps", "bias_z_radps")}
    step |= {k: "scale" for k in PARAMETERS if k.startswith("scale_")}
    return max(abs(v) / CALIBRATION_STEPS[step[k]] for k, v in change.items())
