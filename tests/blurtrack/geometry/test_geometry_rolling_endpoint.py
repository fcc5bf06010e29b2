"""The numpy rolling-shutter endpoint solve (rotation carried from iterate to iterate) against
the kernel's (every iterate integrated afresh) and against a fine integration."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    ROW_TIME_ITERATIONS,
    OmegaFn,
    constant_mat3,
    matmul3,
    matvec3,
    omega_cam_fn,
    project_c,
    relative_rotation,
    rolling_endpoint_c,
    rolling_endpoint_np,
    row_start_c,
    transpose3,
    unproject_c,
    warp_c,
)

INTRINSICS = (1000.0, 1000.0, 639.5, 359.5)
DIST = (-0.2, 0.05, 1e-3, -5e-4)
READOUT_S, HEIGHT, EXPOSURE_S = 0.03, 720, 0.02

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]


def _shake(seed: int, amp_radps: float) -> GyroTrace:
    """Hand shake at 1 kHz, about ``amp_radps``, changing within a frame."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 1.0, 1e-3)
    w = amp_radps * np.sin(2 * np.pi * rng.uniform(2, 9, 3) * t[:, None] + rng.uniform(0, 6, 3))
    w += np.cumsum(rng.normal(0, 0.01, (t.size, 3)), axis=0)
    return GyroTrace(t, w)


def _case(seed: int, amp_radps: float, ref_s: float) -> tuple[np.ndarray, ...]:
    """Pixels ``u, v``, their reference times (``ref_s`` after their row's start) and frame
    times, 200 streaks of a frame at 0.4 s."""
    rng = np.random.default_rng(seed)
    n = 200
    u, v = rng.uniform(0, 1279, n), rng.uniform(0, 719, n)
    ft = np.full(n, 0.4)
    return u, v, ft + READOUT_S * v / HEIGHT + ref_s, ft


def _omega(seed: int, amp_radps: float) -> OmegaFn:
    R_ci = constant_mat3(np.eye(3))
    return omega_cam_fn(_shake(seed, amp_radps).omega_components, R_ci, (0.0, 0.0, 0.0), 0.0)


def _kernel(case: tuple[np.ndarray, ...], omega: OmegaFn, n_sub: int, off_s: float) -> Arrays:
    u, v, t_ref, ft = case
    off = np.full(u.size, off_s)
    args = (u, v, t_ref, ft, off, READOUT_S, HEIGHT, omega, INTRINSICS, DIST, n_sub)
    return rolling_endpoint_c(*args, NUMPY_OPS)


def _carried(case: tuple[np.ndarray, ...], omega: OmegaFn, n_sub: int, off_s: float) -> Arrays:
    u, v, t_ref, ft = case
    off = np.full(u.size, off_s)
    args = (u, v, t_ref, ft, off, READOUT_S, HEIGHT, omega, INTRINSICS, DIST, n_sub)
    return rolling_endpoint_np(*args, 4e-3)


def _reversed(case: tuple[np.ndarray, ...], omega: OmegaFn, n_sub: int, off_s: float) -> Arrays:
    """A wrong solve for the negative control: each update composed on the wrong side."""
    u, v, t_ref, ft = case
    rx, ry, rz = unproject_c(u, v, INTRINSICS, DIST)
    t = row_start_c(ft, v, READOUT_S, HEIGHT) + off_s
    R = relative_rotation(t_ref, t, omega, n_sub)
    for k in range(ROW_TIME_ITERATIONS + 1):
        X, Y, Z = matvec3(transpose3(R), (rx, ry, rz))
        uu, vv = project_c(X, Y, Z, INTRINSICS, DIST)
        if k == ROW_TIME_ITERATIONS:
            return uu, vv, t
        t_next_s = row_start_c(ft, vv, READOUT_S, HEIGHT) + off_s
        R = matmul3(relative_rotation(t, t_next_s, omega, 1), R)
        t = t_next_s
    raise AssertionError


Solver = Callable[[tuple[np.ndarray, ...], OmegaFn, int, float], Arrays]


def _error(
    solve: Solver,
    case: tuple[np.ndarray, ...],
    omega: OmegaFn,
    n_sub: int,
    off_s: float,
    fine: Arrays,
) -> np.ndarray:
    """``(N,)`` px: how far ``solve``'s ends lie from the ``fine`` integration's."""
    u, v, _t = solve(case, omega, n_sub, off_s)
    return np.asarray(np.hypot(u - fine[0], v - fine[1]))


@pytest.mark.parametrize(
    ("amp", "ref_s", "n_sub"),
    [
        (0.8, 0.01, 9),  # the cues' case: the row's mid-exposure, the frame span's sub-steps
        (0.8, 0.01, 40),  # fine sub-steps: the updates must be as fine
        (2.0, -0.06, 80),  # a reference 60 ms before the exposure, fast shake
    ],
)
def test_carried_rotation_solves_as_the_kernel_does(amp: float, ref_s: float, n_sub: int) -> None:
    for seed in (1, 2, 3):
        for off_s in (0.0, EXPOSURE_S):
            case, omega = _case(seed, amp, ref_s), _omega(seed, amp)
            u, v, t_ref, ft = case
            u1, v1, t1 = _carried(case, omega, n_sub, off_s)
            _u0, v0, t0 = _kernel(case, omega, n_sub, off_s)
            fine = _kernel(case, omega, 600, off_s)
            assert np.median(np.hypot(u1 - u, v1 - v)) > 3.0  # the ends move far
            # The fixed point itself: the returned time is the returned row's, as closely
            # as the kernel's four iterations get there.
            miss_np = np.abs(t1 - (ft + READOUT_S * v1 / HEIGHT + off_s))
            miss_kernel = np.abs(t0 - (ft + READOUT_S * v0 / HEIGHT + off_s))
            assert miss_np.max() < 1.5 * miss_kernel.max() + 1e-9
            # Against a fine integration, the error of the kernel's class: its sub-steps
            # sample omega at other midpoints (over seeds 1-8, the 95th percentile of the
            # error 0.84-1.43x the kernel's in the first case, 0.81-1.30x in the second,
            # 0.80-2.42x in the third, where both are under 0.05 px) ...
            err_kernel = _error(_kernel, case, omega, n_sub, off_s, fine)
            err_np = _error(_carried, case, omega, n_sub, off_s, fine)
            p95_kernel = float(np.percentile(err_kernel, 95))
            assert np.percentile(err_np, 95) < 3.0 * p95_kernel + 1e-5
            assert np.median(err_np) < 2.0 * np.median(err_kernel) + 1e-5
            # ... an error small but not nothing in the first case (the comparison is sharp).
            if n_sub == 9 and ref_s > 0:
                assert err_kernel.max() > 1e-3 and err_np.max() < 0.02
            # Negative controls: the first iterate's rotation alone (no update) and the
            # updates composed on the wrong side both miss by far more.
            t_first = ft + READOUT_S * v / HEIGHT + off_s
            ua, va = warp_c(u, v, t_ref, t_first, omega, INTRINSICS, DIST, n_sub)
            assert np.max(np.hypot(ua - u1, va - v1)) > 0.05
            if ref_s < 0:
                err_rev = _error(_reversed, case, omega, n_sub, off_s, fine)
                assert err_rev.max() > 5.0 * err_kernel.max() + 0.05


def test_a_rate_far_beyond_any_shake_keeps_the_sub_steps_bounded() -> None:
    # 60 rad/s (a shake's rates in degrees/s read as radians/s) turns the camera by more than a
    # radian over the exposure: the points leave the sensor, their row times run off, and the
    # updates' sub-steps once grew with them (22 GiB for a session's time-shift scan). Each
    # update now takes at most a whole readout's sub-steps: counted by the rate's evaluations.
    calls: list[int] = []
    R_ci = constant_mat3(np.eye(3))
    trace = GyroTrace(np.arange(0.0, 1.0, 1e-3), np.tile([60.0, 0.0, 0.0], (1000, 1)))
    inner = omega_cam_fn(trace.omega_components, R_ci, (0.0, 0.0, 0.0), 0.0)

    def omega(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        calls.append(np.size(t))
        return inner(t)

    case = _case(3, 1.0, EXPOSURE_S)
    u, v, t_ref, ft = case
    n_sub, step = 5, 4e-3
    out = rolling_endpoint_np(
        u, v, t_ref, ft, np.zeros(u.size), READOUT_S, HEIGHT, omega, INTRINSICS, DIST, n_sub, step
    )
    assert len(out) == 3 and all(np.shape(a) == u.shape for a in out)
    per_update = int(np.ceil(READOUT_S / min(step, EXPOSURE_S / n_sub))) + 1
    assert sum(calls) <= u.size * (n_sub + ROW_TIME_ITERATIONS * per_update)
