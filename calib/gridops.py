"""Numerical helpers of the grid evaluator (:mod:`calib.grid`): row-major 3×3 tuples over
arrays, the prefix scan of rotation steps, the SO(3) left Jacobian, and evaluation of a
CasADi function mapped over a fixed chunk of residuals through zero-copy buffers."""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from blurtrack.geometry.kernels import matmul3

#: Residuals per call of a mapped function (:func:`run_mapped`; the maps of
#: :class:`calib.grid.GridEvaluator` are built for this many).
MAP_CHUNK = 2048


def mat3(a: np.ndarray) -> tuple:
    """``(9, …)`` array -> 9-tuple of arrays."""
    return tuple(a[i] for i in range(9))


def prefix_products(steps: np.ndarray) -> np.ndarray:
    """Cumulative products ``Φ_k = E_0 E_1 … E_{k-1}`` of rotation steps ``(9, M)`` (row-major
    components), returned ``(9, M + 1)`` with ``Φ_0 = I``: a Hillis–Steele scan, ``log2 M``
    vectorised passes."""
    m = steps.shape[1]
    P = steps.copy()
    d = 1
    while d < m:
        prod = matmul3(mat3(P[:, :-d]), mat3(P[:, d:]))
        P[:, d:] = np.stack(prod)
        d *= 2
    eye = np.eye(3).reshape(9, 1)
    return np.concatenate([eye, P], axis=1)


def eye_plus_hat(x: Any, y: Any, z: Any) -> tuple:
    """``I + [(x, y, z)]×`` (row-major 9-tuple): ``exp`` to first order."""
    return (1.0, -z, y, z, 1.0, -x, -y, x, 1.0)


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian ``J_l(ω)``: ``exp([ω + ε]×) = exp([J_l ε]×) exp([ω]×) + O(ε²)``."""
    w = np.asarray(w, float)
    th = float(np.linalg.norm(w))
    Kx = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) + 0.5 * Kx + Kx @ Kx / 6.0
    return np.eye(3) + (1 - np.cos(th)) / th**2 * Kx + (th - np.sin(th)) / th**3 * (Kx @ Kx)


def run_mapped(
    mapped: ca.Function, shared: list[np.ndarray], data: np.ndarray, k: int, p: int
) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate a function mapped over :data:`MAP_CHUNK` residuals with ``shared`` inputs (one
    vector each) and per-residual ``data`` ``(N, n_d)``: its two outputs, ``(N, k)`` and the
    ``(k, p)`` block of each residual as ``(N p, k)``.

    Zero-copy calls through CasADi's buffers (column-major ``(k, n)`` is C-order ``(n, k)``;
    converting numpy arrays to and from DM cost 20x the evaluation itself). Chunks are bound in
    place; the last one is padded with copies of the last residual.
    """
    n, m = data.shape[0], MAP_CHUNK
    d = np.ascontiguousarray(data)
    shared = [np.ascontiguousarray(a, dtype=float) for a in shared]
    r = np.zeros((n, k))
    J = np.zeros((n * p, k))
    buf, run = mapped.buffer()
    for j, a in enumerate(shared):
        buf.set_arg(j, memoryview(a))  # type: ignore[call-arg, arg-type]  # casadi stubs want a size; memoryview form is documented
    for i0 in range(0, n, m):
        i1 = min(i0 + m, n)
        if i1 - i0 == m:
            d_k, r_k, J_k = d[i0:i1], r[i0:i1], J[i0 * p : i1 * p]
        else:
            d_k = np.concatenate([d[i0:i1], np.repeat(d[i1 - 1 : i1], m - (i1 - i0), 0)])
            r_k, J_k = np.zeros((m, k)), np.zeros((m * p, k))
        buf.set_arg(len(shared), memoryview(d_k))  # type: ignore[call-arg, arg-type]
        buf.set_res(0, memoryview(r_k))  # type: ignore[call-arg, arg-type]
        buf.set_res(1, memoryview(J_k))  # type: ignore[call-arg, arg-type]
        run()
        if i1 - i0 < m:
            r[i0:i1], J[i0 * p : i1 * p] = r_k[: i1 - i0], J_k[: (i1 - i0) * p]
    return r, J
