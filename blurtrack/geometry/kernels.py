"""The one gyro-driven blur model, written once for numpy and CasADi.

Every function here takes an ``ops`` namespace (``sin``, ``cos``, ``sqrt``) and uses only
elementwise arithmetic, so the same code evaluates on numpy arrays (prediction, synthesis,
simulation) and on CasADi ``SX``/``MX`` columns (calibration in ``calib``). Batches are carried
component-wise: a batch of 3-vectors is a tuple ``(x, y, z)`` of arrays of shape ``(N,)``; a batch
of rotation matrices is a row-major 9-tuple of arrays. Functions named ``*_c`` take and return such
component tuples ("c" for component-wise). Conventions are those of docs/conventions.md:

- ``R_c(t)`` is the camera orientation (camera to world) at camera time ``t``; the body-frame
  angular velocity ``omega_cam`` drives ``dR/dt = R [omega_cam]_x``.
- ``omega_cam = R_cam_imu M^-1 (omega_imu_meas(t + timeshift_cam_imu) - bias)`` with ``M`` the
  gyro's scale / cross-axis matrix (identity unless calibrated): the measurement model is
  ``omega_meas = M R_cam_imu^T omega_cam + bias + noise``.
- A static direction seen at pixel ``x`` at ``t0`` is seen at ``t1`` at
  ``pi(K R_c(t1)^T R_c(t0) K^-1 x)``.

Rotation integration: ω is sampled at the midpoint of ``n_sub`` equal sub-steps of the interval
and the sub-step rotations ``exp(ω h)`` are composed exactly (second-order midpoint Lie-group
integrator; never a sum of per-axis small angles). With the default sub-step of at most 1 ms its
error is below 1e-6 rad for hand shake; ``relative_rotation_small_angle`` is the source paper's
approximation, kept for comparison only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

#: An elementwise value of a backend: a float or numpy array, or a CasADi ``SX``/``MX`` column.
#: The kernels use only ``+ - * /``, unary minus and the :class:`Backend` functions on it.
Value = Any


class Backend(Protocol):
    """The elementwise functions the kernels take as ``ops``; numpy and CasADi both provide one
    (:data:`NUMPY_OPS` here, ``calib.problem.CA_OPS`` for CasADi)."""

    def sin(self, x: Value, /) -> Value: ...

    def cos(self, x: Value, /) -> Value: ...

    def sqrt(self, x: Value, /) -> Value: ...


class NumpyBackend:
    """:class:`Backend` over numpy arrays and floats."""

    @staticmethod
    def sin(x: Value, /) -> Value:
        return np.sin(x)

    @staticmethod
    def cos(x: Value, /) -> Value:
        return np.cos(x)

    @staticmethod
    def sqrt(x: Value, /) -> Value:
        return np.sqrt(x)


#: numpy implementation of the ops namespace.
NUMPY_OPS: Backend = NumpyBackend()

#: Default longest integration sub-step (seconds).
DEFAULT_MAX_SUBSTEP_S = 1e-3

Vec3 = tuple[Value, Value, Value]
Mat3 = tuple[Value, Value, Value, Value, Value, Value, Value, Value, Value]
OmegaFn = Callable[[Value], Vec3]

# Keeps sqrt differentiable at zero rotation; shifts the angle by at most 1e-12 rad.
_ANGLE_EPS2 = 1e-24


def so3_exp_c(wx: Any, wy: Any, wz: Any, ops: Backend = NUMPY_OPS) -> Mat3:
    """Rodrigues' formula, component-wise: rotation vectors (rad) to 9-tuples.

    >>> R = so3_exp_c(np.array([0.0]), np.array([0.0]), np.array([np.pi / 2]))
    >>> np.round([float(r[0]) for r in R], 12).reshape(3, 3)[:2, :2].tolist()
    [[0.0, -1.0], [1.0, 0.0]]
    """
    # Each product and sum evaluated once (the very operations, in the same order, of the
    # formula written out entry by entry: the same values, a third fewer array operations).
    xx, yy, zz = wx * wx, wy * wy, wz * wz
    xy = xx + yy
    th2 = xy + zz
    th = ops.sqrt(th2 + _ANGLE_EPS2)
    a = ops.sin(th) / th
    s = ops.sin(th / 2) / th
    b = 2 * s * s  # (1 - cos th) / th^2 without cancellation
    bx = b * wx
    bxy, bxz, byz = bx * wy, bx * wz, b * wy * wz
    ax, ay, az = a * wx, a * wy, a * wz
    return (
        1 - b * (yy + zz),
        bxy - az,
        bxz + ay,
        bxy + az,
        1 - b * (xx + zz),
        byz - ax,
        bxz - ay,
        byz + ax,
        1 - b * xy,
    )


def matmul3(A: Mat3, B: Mat3) -> Mat3:
    """Product of two batches of 3x3 matrices given as row-major 9-tuples."""
    return tuple(
        A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j]
        for i in range(3)
        for j in range(3)
    )  # type: ignore[return-value]


def transpose3(A: Mat3) -> Mat3:
    return (A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8])


def matvec3(A: Mat3, v: Vec3) -> Vec3:
    x, y, z = v
    return (
        A[0] * x + A[1] * y + A[2] * z,
        A[3] * x + A[4] * y + A[5] * z,
        A[6] * x + A[7] * y + A[8] * z,
    )


def constant_mat3(R: np.ndarray) -> Mat3:
    """A fixed (3, 3) matrix as a 9-tuple of floats (broadcasts against any batch)."""
    return tuple(float(v) for v in np.asarray(R, dtype=float).reshape(9))  # type: ignore[return-value]


def n_substeps(max_duration_s: float, max_substep_s: float = DEFAULT_MAX_SUBSTEP_S) -> int:
    """Number of integration sub-steps so that none is longer than ``max_substep_s``."""
    return max(1, math.ceil(abs(max_duration_s) / max_substep_s - 1e-9))


def relative_rotation(
    t_from_s: Any, t_to_s: Any, omega_cam_at: OmegaFn, n_sub: int, ops: Backend = NUMPY_OPS
) -> Mat3:
    """``R_c(t_from)^T R_c(t_to)`` for batches of camera-time intervals.

    Args:
        t_from_s, t_to_s: interval ends, camera clock, seconds, shape ``(N,)`` (``t_to`` may be
            earlier than ``t_from``).
        omega_cam_at: ``t_cam_s (N,) -> (wx, wy, wz)``, camera-frame angular velocity, rad/s.
        n_sub: number of equal sub-steps (see :func:`n_substeps`).

    Returns:
        Row-major 9-tuple of ``(N,)`` arrays.

    >>> w = lambda t: (0 * t, 0 * t, 0 * t + 2.0)
    >>> R = relative_rotation(np.array([0.0]), np.array([0.25]), w, 4)
    >>> round(float(R[3][0]), 12)  # sin(0.5)
    0.479425538604
    """
    h = (t_to_s - t_from_s) / n_sub
    if ops is NUMPY_OPS and n_sub > 1 and isinstance(h, np.ndarray) and h.ndim == 1:
        return _relative_rotation_np(np.asarray(t_from_s, float), h, omega_cam_at, n_sub)
    R: Mat3 | None = None
    for k in range(n_sub):
        wx, wy, wz = omega_cam_at(t_from_s + (k + 0.5) * h)
        step = so3_exp_c(wx * h, wy * h, wz * h, ops)
        R = step if R is None else matmul3(R, step)
    assert R is not None
    return R


def _relative_rotation_np(
    t_from_s: np.ndarray, h: np.ndarray, omega_cam_at: OmegaFn, n_sub: int
) -> Mat3:
    """:func:`relative_rotation` on numpy arrays ``(N,)`` with ω and the sub-step rotations
    evaluated for all ``n_sub`` sub-steps at once (``(n_sub, N)`` arrays; the same elementwise
    arithmetic, so the same values as the loop: 30x fewer array operations on a 300-pair axis
    search)."""
    t_mid = t_from_s + (np.arange(n_sub, dtype=float)[:, None] + 0.5) * h
    # omega functions take 1-D times (an (N, 3) gyro lookup flattens nothing): ask flat, reshape
    wx, wy, wz = (np.asarray(w, float).reshape(t_mid.shape) for w in omega_cam_at(t_mid.ravel()))
    steps = so3_exp_c(wx * h, wy * h, wz * h, NUMPY_OPS)
    R: Mat3 = tuple(c[0] for c in steps)  # type: ignore[assignment]
    for k in range(1, n_sub):
        R = matmul3(R, tuple(c[k] for c in steps))  # type: ignore[arg-type]
    return R


def relative_rotation_small_angle(
    t_from_s: Any, t_to_s: Any, omega_cam_at: OmegaFn, n_sub: int, ops: Backend = NUMPY_OPS
) -> Mat3:
    """The source paper's approximation: per-axis angles summed, then ``Rz Ry Rx``.

    Kept only to compare motion models in reports and the ``paper`` synthesis mode.
    """
    h = (t_to_s - t_from_s) / n_sub
    ax = ay = az = 0 * t_from_s
    for k in range(n_sub):
        wx, wy, wz = omega_cam_at(t_from_s + (k + 0.5) * h)
        ax, ay, az = ax + wx * h, ay + wy * h, az + wz * h
    zero = 0 * t_from_s
    Rx = so3_exp_c(ax, zero, zero, ops)
    Ry = so3_exp_c(zero, ay, zero, ops)
    Rz = so3_exp_c(zero, zero, az, ops)
    return matmul3(Rz, matmul3(Ry, Rx))


def omega_cam_fn(
    omega_imu_at: OmegaFn, R_cam_imu: Mat3, bias_radps: Vec3, timeshift_cam_imu_s: Any
) -> OmegaFn:
    """Camera-frame angular velocity on the camera clock from the IMU's measured rate.

    ``omega_imu_at`` takes IMU-clock times (``t_imu = t_cam + timeshift_cam_imu``).
    """

    def omega_cam_at(t_cam_s: Any) -> Vec3:
        wx, wy, wz = omega_imu_at(t_cam_s + timeshift_cam_imu_s)
        return matvec3(R_cam_imu, (wx - bias_radps[0], wy - bias_radps[1], wz - bias_radps[2]))

    return omega_cam_at


def distort(x: Any, y: Any, dist: Sequence[Any]) -> tuple[Any, Any]:
    """radtan (OpenCV k1 k2 p1 p2) distortion of normalised coordinates; ``()`` is none."""
    if len(dist) == 0:
        return x, y
    k1, k2, p1, p2 = dist
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


#: Newton iterations of :func:`undistort` (a fixed count keeps it a CasADi expression).
UNDISTORT_ITERATIONS = 8


def undistort(xd: Any, yd: Any, dist: Sequence[Any]) -> tuple[Any, Any]:
    """Inverse of :func:`distort` by Newton's method from the distorted point.

    Converges quadratically for lens-like radtan distortion (1e-12 within the image circle of
    ordinary lenses after the fixed iteration count).
    """
    if len(dist) == 0:
        return xd, yd
    k1, k2, p1, p2 = dist
    x, y = xd, yd
    for _ in range(UNDISTORT_ITERATIONS):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        g = 2 * (k1 + 2 * k2 * r2)  # d radial / d(x, y) = g * (x, y)
        fx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        fy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        j11 = radial + g * x * x + 2 * p1 * y + 6 * p2 * x
        j12 = g * x * y + 2 * p1 * x + 2 * p2 * y
        j21 = g * x * y + 2 * p1 * x + 2 * p2 * y
        j22 = radial + g * y * y + 6 * p1 * y + 2 * p2 * x
        det = j11 * j22 - j12 * j21
        x, y = x - (j22 * fx - j12 * fy) / det, y - (j11 * fy - j21 * fx) / det
    return x, y


def project_c(X: Any, Y: Any, Z: Any, intrinsics: Sequence[Any], dist: Sequence[Any]) -> tuple:
    """Pinhole projection of camera-frame points (any scale) to pixels ``(u, v)``."""
    fx, fy, cx, cy = intrinsics
    xd, yd = distort(X / Z, Y / Z, dist)
    return fx * xd + cx, fy * yd + cy


def unproject_c(u: Any, v: Any, intrinsics: Sequence[Any], dist: Sequence[Any]) -> Vec3:
    """Pixels to camera-frame rays with ``z = 1``."""
    fx, fy, cx, cy = intrinsics
    x, y = undistort((u - cx) / fx, (v - cy) / fy, dist)
    return x, y, 0 * x + 1


def warp_c(
    u: Any,
    v: Any,
    t_from_s: Any,
    t_to_s: Any,
    omega_cam_at: OmegaFn,
    intrinsics: Sequence[Any],
    dist: Sequence[Any],
    n_sub: int,
    ops: Backend = NUMPY_OPS,
    rotation: Callable[..., Mat3] = relative_rotation,
) -> tuple[Any, Any]:
    """Where a static direction seen at pixel ``(u, v)`` at ``t_from`` is seen at ``t_to``.

    ``pi(K R_c(t_to)^T R_c(t_from) K^-1 x)``, camera clock, pixels, batched elementwise.
    """
    R = rotation(t_from_s, t_to_s, omega_cam_at, n_sub, ops)
    ray = unproject_c(u, v, intrinsics, dist)
    X, Y, Z = matvec3(transpose3(R), ray)
    return project_c(X, Y, Z, intrinsics, dist)


def row_start_c(frame_t_s: Any, row: Any, readout_s: Any, height: int) -> Any:
    """Start of exposure of (continuous) image row ``row``: ``t + readout * row / H``."""
    return frame_t_s + readout_s * row / height


#: Fixed-point iterations that solve the rolling-shutter row time of a moving point.
ROW_TIME_ITERATIONS = 4


def rolling_endpoint_c(
    u_ref: Any,
    v_ref: Any,
    t_ref_s: Any,
    frame_t_s: Any,
    offset_s: Any,
    readout_s: Any,
    height: int,
    omega_cam_at: OmegaFn,
    intrinsics: Sequence[Any],
    dist: Sequence[Any],
    n_sub: int,
    ops: Backend = NUMPY_OPS,
    rotation: Callable[..., Mat3] = relative_rotation,
) -> tuple[Any, Any, Any]:
    """Where, and when, a moving point crosses its row's start (+ ``offset_s``) of exposure.

    Solves ``t = frame_t + readout * v(t) / H + offset`` with ``v(t)`` the point's image row at
    ``t`` (``offset_s = 0`` gives a streak's start, ``exposure_s`` its end).

    Returns:
        ``(u, v, t)`` arrays: endpoint pixel and its camera time.
    """
    t = row_start_c(frame_t_s, v_ref, readout_s, height) + offset_s
    u, v = u_ref, v_ref
    for _ in range(ROW_TIME_ITERATIONS):
        u, v = warp_c(
            u_ref, v_ref, t_ref_s, t, omega_cam_at, intrinsics, dist, n_sub, ops, rotation
        )
        t = row_start_c(frame_t_s, v, readout_s, height) + offset_s
    u, v = warp_c(u_ref, v_ref, t_ref_s, t, omega_cam_at, intrinsics, dist, n_sub, ops, rotation)
    return u, v, t


def rolling_endpoint_np(
    u_ref: np.ndarray,
    v_ref: np.ndarray,
    t_ref_s: np.ndarray,
    frame_t_s: np.ndarray,
    offset_s: np.ndarray,
    readout_s: float,
    height: int,
    omega_cam_at: OmegaFn,
    intrinsics: Sequence[float],
    dist: Sequence[float],
    n_sub: int,
    max_substep_s: float = DEFAULT_MAX_SUBSTEP_S,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rolling_endpoint_c` on numpy arrays ``(N,)`` (the ``exact`` rotation model), the
    rotation carried from iterate to iterate: ``R(t_ref -> t_k+1) = R(t_ref -> t_k) R(t_k ->
    t_k+1)``.

    The first iterate's rotation is integrated as the kernel does (``n_sub`` sub-steps); each
    fixed-point update then integrates only the row time's change, in as many sub-steps as its
    longest needs (none longer than ``max_substep_s``, nor than the first iterate's sub-steps;
    the change contracts by ``readout * speed / height`` per iterate, so after the first
    update one sub-step does). The same solve, to the kernel's integration error (the tests
    compare both with a fine integration), at about ``(n_sub + 4) / (5 n_sub)`` of its rotation
    exponentials: the kernel integrates every iterate afresh.
    """
    rx, ry, rz = unproject_c(u_ref, v_ref, intrinsics, dist)
    t_s = row_start_c(frame_t_s, v_ref, readout_s, height) + offset_s
    R = relative_rotation(t_ref_s, t_s, omega_cam_at, n_sub)
    # The first iterate's sub-step: updates take sub-steps no longer than it.
    first_h = float(np.nanmax(np.abs(t_s - t_ref_s), initial=0.0)) / max(n_sub, 1)
    step_s = min(max_substep_s, first_h) if first_h > 0 else max_substep_s
    # An update's sub-steps are bounded by a whole readout's: a row time moves by more only
    # for a point projected off the sensor (a rate far beyond any shake: a gyro in degrees/s
    # read as radians/s), whose row time means nothing; unbounded, its sub-steps asked 22 GiB
    # for a session's time-shift scan.
    cap = n_substeps(abs(float(readout_s)), step_s) + 1
    for k in range(ROW_TIME_ITERATIONS + 1):
        X, Y, Z = matvec3(transpose3(R), (rx, ry, rz))
        u, v = project_c(X, Y, Z, intrinsics, dist)
        if k == ROW_TIME_ITERATIONS:
            break
        t_next_s = row_start_c(frame_t_s, v, readout_s, height) + offset_s
        m = min(n_substeps(float(np.nanmax(np.abs(t_next_s - t_s), initial=0.0)), step_s), cap)
        R = matmul3(R, relative_rotation(t_s, t_next_s, omega_cam_at, m))
        t_s = t_next_s
    return u, v, t_s
