"""Point tracks sampled at increasing times, integrated sample to sample.

:func:`blurtrack.geometry.kernels.warp_c` integrates the rotation from the reference time to
every sample time afresh, ``n_sub`` midpoint sub-steps each: a track of ``T`` samples costs
``T * n_sub`` rotation exponentials per point. Along a track whose times increase, the rotation
to sample ``k + 1`` is the rotation to sample ``k`` times the short step between them, so one
exponential per sample does (:func:`ordered_point_track`): the same midpoint Lie-group
integrator (docs/conventions.md), on the samples' own, finer grid (a streak's 65 samples are
< 1 ms apart, against the detection models' 4 ms sub-steps), composed once along the track.
The kernel stays the reference (``tests/blurtrack/geometry/test_geometry_ordered_track.py``
compares the two to 1e-6 px); the gyro-direction check's tracks use this one
(:mod:`blurtrack.detect.gyro.direction`). Detection's predicted curves read a grid of the
orientation instead (:mod:`blurtrack.geometry.orientation_grid`: the same integrator on a
finer grid shared by a frame's streaks).
"""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    OmegaFn,
    n_substeps,
    project_c,
    so3_exp_c,
    unproject_c,
)


def _step_rotations(
    t0_s: np.ndarray, dt_s: np.ndarray, omega_cam_at: OmegaFn, max_substep_s: float
) -> np.ndarray:
    """``R_c(t0)^T R_c(t0 + dt)`` for every interval, ``(..., 3, 3)``: midpoint sub-steps, as
    many as the longest interval needs (:func:`~blurtrack.geometry.kernels.n_substeps`)."""
    m = n_substeps(float(np.max(np.abs(dt_s), initial=0.0)), max_substep_s)
    h = dt_s / m
    out: np.ndarray | None = None
    for j in range(m):
        t_mid = (t0_s + (j + 0.5) * h).ravel()
        wx, wy, wz = (np.asarray(w, float).reshape(h.shape) for w in omega_cam_at(t_mid))
        step = np.stack(so3_exp_c(wx * h, wy * h, wz * h, NUMPY_OPS), axis=-1)
        step = step.reshape(*h.shape, 3, 3)
        out = step if out is None else out @ step
    assert out is not None
    return out


def ordered_point_track(
    pixels: np.ndarray,
    t_ref_s: np.ndarray,
    times_s: np.ndarray,
    omega_cam_at: OmegaFn,
    intrinsics: tuple[float, float, float, float],
    dist: tuple[float, ...],
    max_substep_s: float,
) -> np.ndarray:
    """Image positions of static directions seen at ``pixels`` at ``t_ref_s``, at ``times_s``.

    Args:
        pixels: ``(N, 2)`` pixels at the reference times.
        t_ref_s: ``(N,)`` reference times, camera clock, seconds.
        times_s: ``(N, T)`` sample times, camera clock, seconds, non-decreasing along each row
            (``ValueError`` otherwise: :meth:`BlurModel.point_track` takes any order).
        omega_cam_at: camera-frame angular velocity, ``t (M,) -> (wx, wy, wz)``, rad/s.
        intrinsics, dist: the camera's ``(fx, fy, cx, cy)`` and radtan coefficients.
        max_substep_s: longest integration sub-step, seconds.

    Returns:
        ``(N, T, 2)`` pixels: ``pi(K R_c(t)^T R_c(t_ref) K^-1 x)``, as ``warp_c``.
    """
    px = np.asarray(pixels, float).reshape(-1, 2)
    t = np.asarray(times_s, float)
    n, T = t.shape
    t_ref = np.broadcast_to(np.asarray(t_ref_s, float), (n,))
    if T > 1 and np.any(np.diff(t, axis=1) < 0):
        raise ValueError("ordered_point_track needs times that do not decrease along a track")
    # The reference time joins each row's samples at its place: s (N, T + 1), sorted.
    at = np.sum(t < t_ref[:, None], axis=1)  # (N,) the reference's column in s
    col = np.arange(T + 1)[None, :]
    src = np.clip(col - (col > at[:, None]), 0, T - 1)  # s's column -> t's column
    s = np.where(col == at[:, None], t_ref[:, None], np.take_along_axis(t, src, axis=1))
    # Orientation along each row relative to its first entry: prefix products of the steps.
    steps = _step_rotations(s[:, :-1], np.diff(s, axis=1), omega_cam_at, max_substep_s)
    P = np.empty((n, T + 1, 3, 3))
    P[:, 0] = np.eye(3)
    for k in range(T):
        np.matmul(P[:, k], steps[:, k], out=P[:, k + 1])
    # X = R_rel^T ray with R_rel = R_c(t_ref)^T R_c(t) = P_ref^T P_t: X = P_t^T (P_ref ray).
    rx, ry, rz = unproject_c(px[:, 0], px[:, 1], intrinsics, dist)
    ray = np.stack([rx, ry, rz], axis=-1)  # (N, 3)
    P_ref = P[np.arange(n), at]  # (N, 3, 3)
    v = np.einsum("nij,nj->ni", P_ref, ray)
    # X_s[n, s, i] = sum_j P[n, s, j, i] v[n, j], summed in j's order (einsum's values on this
    # build, up to the sign of a zero; at half its time), only at the samples' columns (the
    # reference's left out).
    at_sample = col != at[:, None]  # (N, T + 1): True at the T samples' columns of each row
    Q = P[at_sample].reshape(n, T, 3, 3)
    X = Q[:, :, 0, :] * v[:, None, 0, None] + Q[:, :, 1, :] * v[:, None, 1, None]
    X += Q[:, :, 2, :] * v[:, None, 2, None]
    u, w = project_c(X[..., 0], X[..., 1], X[..., 2], intrinsics, dist)
    return np.stack([u, w], axis=-1)
