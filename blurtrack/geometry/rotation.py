"""Rotations as batched numpy arrays: SO(3) exponential and logarithm, quaternions.

Rotation vectors are axis * angle in radians, shape ``(..., 3)``; matrices ``(..., 3, 3)``;
quaternions ``(..., 4)`` in ``(w, x, y, z)`` order, unit norm. The CasADi-compatible
component-wise forms used by the blur model live in :mod:`blurtrack.geometry.kernels`.
"""

from __future__ import annotations

import numpy as np

from blurtrack.errors import GeometryError
from blurtrack.geometry.kernels import so3_exp_c


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices ``[v]_x`` of vectors ``(..., 3)`` -> ``(..., 3, 3)``.

    >>> hat(np.array([1.0, 2.0, 3.0])) @ np.array([4.0, 5.0, 6.0])
    array([-3.,  6., -3.])
    """
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([z, -w, y, w, z, -x, -y, x, z], axis=-1).reshape((*v.shape[:-1], 3, 3))


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors ``(..., 3)`` (rad).

    >>> np.round(so3_exp(np.array([0.0, 0.0, np.pi / 2])), 12)[0].tolist()
    [0.0, -1.0, 0.0]
    """
    rv = np.asarray(rotvec, dtype=float)
    if rv.shape[-1:] != (3,):
        raise GeometryError(f"rotation vectors must have shape (..., 3), got {rv.shape}")
    comps = so3_exp_c(rv[..., 0], rv[..., 1], rv[..., 2])
    return np.stack(comps, axis=-1).reshape((*rv.shape[:-1], 3, 3))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` of rotation matrices ``(..., 3, 3)``; angles in [0, pi]."""
    return quat_to_rotvec(matrix_to_quat(R))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` from rotation matrices."""
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise GeometryError(f"rotation matrices must have shape (..., 3, 3), got {R.shape}")
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    # Four candidate formulas; pick per matrix the one with the largest (best conditioned) root.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for i in range(4):
        sel = k == i
        if not np.any(sel):
            continue
        a = m[sel]
        if i == 0:
            s = np.sqrt(1.0 + tr[sel]) * 2
            q[sel] = np.stack(
                [
                    0.25 * s,
                    (a[:, 2, 1] - a[:, 1, 2]) / s,
                    (a[:, 0, 2] - a[:, 2, 0]) / s,
                    (a[:, 1, 0] - a[:, 0, 1]) / s,
                ],
                1,
            )
        else:
            j, l = (i % 3), ((i + 1) % 3)
            ii = i - 1
            s = np.sqrt(1.0 + a[:, ii, ii] - a[:, j, j] - a[:, l, l]) * 2
            vec = np.empty((a.shape[0], 3))
            vec[:, ii] = 0.25 * s
            vec[:, j] = (a[:, j, ii] + a[:, ii, j]) / s
            vec[:, l] = (a[:, l, ii] + a[:, ii, l]) / s
            w = (a[:, l, j] - a[:, j, l]) / s
            q[sel] = np.concatenate([w[:, None], vec], axis=1)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape((*R.shape[:-2], 4))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors from unit quaternions ``(w, x, y, z)``."""
    q = np.asarray(q, dtype=float)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2 * np.arctan2(s, q[..., 0])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0 / np.maximum(q[..., 0], 1e-300))
    return v * scale[..., None]


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotation ``R_a^T R_b``: the distance between two rotations."""
    d = np.swapaxes(np.asarray(R_a), -1, -2) @ np.asarray(R_b)
    return np.degrees(np.linalg.norm(so3_log(d), axis=-1))


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """Whether ``R`` (3, 3) is orthonormal with determinant +1 within ``tol``."""
    R = np.asarray(R, dtype=float)
    return (
        R.shape == (3, 3)
        and bool(np.all(np.isfinite(R)))
        and np.allclose(R.T @ R, np.eye(3), atol=tol)
        and abs(np.linalg.det(R) - 1.0) < tol
    )
