"""The CasADi evaluation of blurtrack.geometry.kernels equals the numpy one (one model, two
backends)."""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np

from blurtrack.geometry.kernels import constant_mat3, omega_cam_fn, rolling_endpoint_c, warp_c

CA_OPS = SimpleNamespace(sin=ca.sin, cos=ca.cos, sqrt=ca.sqrt)


def test_casadi_twin_equals_numpy_to_1e9() -> None:
    rng = np.random.default_rng(5)
    t_imu = np.arange(0.0, 1.0, 0.005)
    w_imu = np.cumsum(rng.normal(0, 0.3, (t_imu.size, 3)), axis=0)
    R = constant_mat3(np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]]))
    bias = (0.01, -0.02, 0.005)
    intr = (1000.0, 990.0, 640.0, 360.0)
    dist = (-0.2, 0.05, 1e-3, -1e-3)
    n = 40
    u = rng.uniform(0, 1280, n)
    v = rng.uniform(0, 720, n)
    t0 = rng.uniform(0.2, 0.7, n)
    t1 = t0 + rng.uniform(-0.03, 0.03, n)

    def np_omega(t):
        return tuple(np.interp(t, t_imu, w_imu[:, k]) for k in range(3))

    interp = [ca.interpolant(f"w{k}", "linear", [t_imu], w_imu[:, k]) for k in range(3)]

    def ca_omega(t):
        return tuple(f(t) for f in interp)

    shift = 0.0123
    ref = warp_c(u, v, t0, t1, omega_cam_fn(np_omega, R, bias, shift), intr, dist, 30)
    # Symbolic in the time shift and the intrinsics, evaluated at the same values.
    s = ca.MX.sym("shift")
    k = ca.MX.sym("k", 4)
    U, V = ca.DM(u), ca.DM(v)
    uu, vv = warp_c(
        U,
        V,
        ca.DM(t0),
        ca.DM(t1),
        omega_cam_fn(ca_omega, R, bias, s),
        (k[0], k[1], k[2], k[3]),
        dist,
        30,
        CA_OPS,
    )
    f = ca.Function("f", [s, k], [uu, vv])
    got_u, got_v = f(shift, intr)
    np.testing.assert_allclose(np.asarray(got_u).ravel(), ref[0], atol=1e-9, rtol=0)
    np.testing.assert_allclose(np.asarray(got_v).ravel(), ref[1], atol=1e-9, rtol=0)

    ro = rolling_endpoint_c(
        u, v, t0, t0 - 0.01, 0.02, 0.03, 720, omega_cam_fn(np_omega, R, bias, shift), intr, dist, 30
    )
    g = ca.Function(
        "g",
        [s],
        list(
            rolling_endpoint_c(
                U,
                V,
                ca.DM(t0),
                ca.DM(t0 - 0.01),
                0.02,
                0.03,
                720,
                omega_cam_fn(ca_omega, R, bias, s),
                intr,
                dist,
                30,
                CA_OPS,
            )
        ),
    )
    for a, b in zip(g(shift), ro, strict=True):
        np.testing.assert_allclose(np.asarray(a).ravel(), b, atol=1e-9, rtol=0)
