"""The numpy rolling-shutter endpoint solve (rotation carried from iterate to iterate) against
the kernel's (every iterate integrated afresh) and against a fine integration."""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    constant_mat3,
    omega_cam_fn,
    rolling_endpoint_c,
    rolling_endpoint_np,
    warp_c,
)

INTRINSICS = (1000.0, 1000.0, 639.5, 359.5)
DIST = (-0.2, 0.05, 1e-3, -5e-4)
READOUT_S, HEIGHT = 0.03, 720


def _shake(seed: int) -> GyroTrace:
    """Fast hand shake: 1 kHz, about 1 rad/s, changing within a frame."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 1.0, 1e-3)
    w = 0.8 * np.sin(2 * np.pi * rng.uniform(2, 9, 3) * t[:, None] + rng.uniform(0, 6, 3))
    w += np.cumsum(rng.normal(0, 0.01, (t.size, 3)), axis=0)
    return GyroTrace(t, w)


def _solve(seed: int, fn, n_sub: int, offset_s: float):
    rng = np.random.default_rng(seed)
    n = 400
    u = rng.uniform(0, 1279, n)
    v = rng.uniform(0, 719, n)
    ft = np.full(n, 0.4)
    t_ref = ft + READOUT_S * v / HEIGHT + 0.01  # the row's mid-exposure (20 ms)
    R_ci = constant_mat3(np.eye(3))
    omega = omega_cam_fn(_shake(seed).omega_components, R_ci, (0.0, 0.0, 0.0), 0.0)
    off = np.full(n, offset_s)
    if fn is rolling_endpoint_np:
        args = (u, v, t_ref, ft, off, READOUT_S, HEIGHT, omega, INTRINSICS, DIST, n_sub)
        return (u, v, t_ref, ft, omega), fn(*args)
    out = fn(u, v, t_ref, ft, off, READOUT_S, HEIGHT, omega, INTRINSICS, DIST, n_sub, NUMPY_OPS)
    return (u, v, t_ref, ft, omega), out


def test_carried_rotation_solves_as_the_kernel_does() -> None:
    for seed in (1, 2, 3):
        for offset in (0.0, 0.02):
            (u, v, t_ref, ft, omega), (u1, v1, t1) = _solve(seed, rolling_endpoint_np, 9, offset)
            _, (u0, v0, t0) = _solve(seed, rolling_endpoint_c, 9, offset)
            _, (uf, vf, _tf) = _solve(seed, rolling_endpoint_c, 400, offset)
            moved = np.hypot(u1 - u, v1 - v)
            assert np.median(moved) > 3.0  # the streak ends are far from the reference
            # The fixed point itself: the returned time is the returned row's (to the
            # kernel's four iterations at up to ~2000 px/s: 1.6e-8 s, 3e-5 px).
            np.testing.assert_allclose(t1, ft + READOUT_S * v1 / HEIGHT + offset, atol=1e-7)
            np.testing.assert_allclose(t1, t0, atol=1e-6)
            # Against a fine integration, the error of the kernel's class (its sub-steps
            # sample omega at other midpoints: 0.76-1.48x the kernel's largest over seeds 1-8)
            # and far below the cues' scatter (1.5 px) ...
            err_kernel = np.hypot(u0 - uf, v0 - vf)
            err_np = np.hypot(u1 - uf, v1 - vf)
            assert err_np.max() < 1.6 * err_kernel.max()
            assert np.median(err_np) < 1.3 * np.median(err_kernel)
            assert err_np.max() < 0.01
            # ... an error small but not nothing (the comparison is sharp).
            assert err_kernel.max() > 1e-3
            # Negative control: the rotation of the first iterate alone (no carried update)
            # misses the solution by far more than the tolerance above.
            t_first = ft + READOUT_S * v / HEIGHT + offset
            ua, va = warp_c(u, v, t_ref, t_first, omega, INTRINSICS, DIST, 9)
            assert np.max(np.hypot(ua - u1, va - v1)) > 0.05
