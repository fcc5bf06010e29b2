"""The numpy fast paths of the gyro integration give bit for bit the values of the plain
code: blurtrack.geometry.kernels.relative_rotation with all sub-steps at once against the
step-by-step loop, GyroTrace's contiguous columns against ``np.interp`` on its own columns,
its cached upsampling against a fresh one."""

from __future__ import annotations

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    Mat3,
    constant_mat3,
    matmul3,
    omega_cam_fn,
    relative_rotation,
    so3_exp_c,
)


def _trace(seed: int = 2) -> GyroTrace:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, 3000))
    w = np.cumsum(rng.normal(0, 0.05, (t.size, 3)), axis=0)
    return GyroTrace(t, w)


def _loop(t0: np.ndarray, t1: np.ndarray, omega, n_sub: int) -> Mat3:
    h = (t1 - t0) / n_sub
    R = None
    for k in range(n_sub):
        wx, wy, wz = omega(t0 + (k + 0.5) * h)
        step = so3_exp_c(wx * h, wy * h, wz * h, NUMPY_OPS)
        R = step if R is None else matmul3(R, step)
    assert R is not None
    return R


@pytest.mark.parametrize("n_sub", [1, 2, 9, 40])
def test_relative_rotation_equals_the_step_by_step_loop(n_sub: int) -> None:
    g = _trace()
    rng = np.random.default_rng(n_sub)
    t0 = np.sort(rng.uniform(0.1, 2.5, 500))
    t1 = t0 + rng.uniform(-0.04, 0.04, t0.size)
    R_ci = constant_mat3(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]))
    omega = omega_cam_fn(g.omega_components, R_ci, (0.01, -0.02, 0.003), 0.004)
    got = relative_rotation(t0, t1, omega, n_sub)
    ref = _loop(t0, t1, omega, n_sub)
    assert all(np.array_equal(x, y) for x, y in zip(got, ref, strict=True))
    # the rotations are not trivial, and a sub-step more changes them (the check is sharp)
    assert np.max(np.abs(got[1])) > 1e-3
    other = _loop(t0, t1, omega, n_sub + 1)
    assert not all(np.array_equal(x, y) for x, y in zip(got, other, strict=True))


def test_gyro_interpolation_equals_np_interp_of_its_columns() -> None:
    g = _trace(4)
    t = np.random.default_rng(1).uniform(g.t_s[0] - 0.01, g.t_s[-1] + 0.01, 2000)
    t[:5] = g.t_s[[0, 7, 100, -2, -1]]  # on the samples and at both ends
    ref = np.stack([np.interp(t, g.t_s, g.omega_radps[:, k]) for k in range(3)], axis=1)
    assert np.array_equal(g.omega_at(t), ref)
    assert all(np.array_equal(c, ref[:, k]) for k, c in enumerate(g.omega_components(t)))
    assert np.array_equal(g.omega_at(t[:5]), g.omega_radps[[0, 7, 100, -2, -1]])


def test_upsampled_trace_is_computed_once_and_equals_a_fresh_resampling() -> None:
    g = _trace(5)
    up = g.upsampled(8)
    assert g.upsampled(8) is up and g.upsampled(1) is g
    fresh = GyroTrace(g.t_s.copy(), g.omega_radps.copy()).upsampled(8)
    assert np.array_equal(up.t_s, fresh.t_s) and np.array_equal(up.omega_radps, fresh.omega_radps)
    other = g.upsampled(4)
    assert other.t_s.size != up.t_s.size  # the cache is per factor


def test_so3_exp_is_the_formula_written_out_bit_for_bit() -> None:
    """:func:`so3_exp_c` evaluates each shared product once; its values are exactly those of
    Rodrigues' formula written out entry by entry (the same operations in the same order)."""
    from blurtrack.geometry.kernels import _ANGLE_EPS2, so3_exp_c

    def written_out(wx, wy, wz):
        th = np.sqrt(wx * wx + wy * wy + wz * wz + _ANGLE_EPS2)
        a = np.sin(th) / th
        s = np.sin(th / 2) / th
        b = 2 * s * s
        return (
            1 - b * (wy * wy + wz * wz),
            b * wx * wy - a * wz,
            b * wx * wz + a * wy,
            b * wx * wy + a * wz,
            1 - b * (wx * wx + wz * wz),
            b * wy * wz - a * wx,
            b * wx * wz - a * wy,
            b * wy * wz + a * wx,
            1 - b * (wx * wx + wy * wy),
        )

    rng = np.random.default_rng(3)
    for scale in (1e-4, 1e-2, 1.0, 3.0):
        w = tuple(rng.normal(0.0, scale, 5000) for _ in range(3))
        got, ref = so3_exp_c(*w), written_out(*w)
        assert all(np.array_equal(g, r) for g, r in zip(got, ref, strict=True))
    # Negative control: the exact comparison sees a change of association alone.
    wx, wy, wz = w
    th = np.sqrt(wx * wx + wy * wy + wz * wz + _ANGLE_EPS2)
    b = 2 * (np.sin(th / 2) / th) ** 2
    assert not np.array_equal(b * wx * wy, b * (wx * wy))
    # Scalars (the CasADi path takes the same code on symbols).
    R = so3_exp_c(0.1, -0.2, 0.3)
    assert all(float(x) == float(y) for x, y in zip(R, written_out(0.1, -0.2, 0.3), strict=True))
