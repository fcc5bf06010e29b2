"""Blur heat maps (docs/conventions.md): trajectory endpoints and quadratic Bézier control points.

A pixel's trajectory ``q(τ)``, ``τ ∈ [0, 1]`` over its row's exposure, is summarised by
``q(0)``, ``q(1)`` and the control point ``P`` of ``B(τ) = (1-τ)² q(0) + 2τ(1-τ) P + τ² q(1)``
fitted by least squares to the sampled ``q`` with the endpoints held fixed. Stored as one
float32 array ``(6, H, W)``: ``q(0).x, q(0).y, q(1).x, q(1).y, P.x, P.y`` in pixels.
"""

from __future__ import annotations

import numpy as np

from blurtrack.errors import GeometryError

#: Channel names of a heat-map array, in order.
CHANNELS = ("q0_x", "q0_y", "q1_x", "q1_y", "ctrl_x", "ctrl_y")


def bezier_fit(q: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Control points ``(..., 2)`` and max fit errors ``(...)`` (px) of trajectories.

    Args:
        q: sampled trajectories ``(..., T, 2)``, pixels, with ``q[..., 0, :] = q(0)`` and
            ``q[..., -1, :] = q(1)``.
        tau: sample parameters ``(T,)`` in ``[0, 1]``, first 0 and last 1.

    >>> tau = np.linspace(0, 1, 5)
    >>> P = np.array([1.0, 3.0])
    >>> curve = (2 * tau * (1 - tau))[:, None] * P + (tau**2)[:, None] * np.array([4.0, 0.0])
    >>> ctrl, err = bezier_fit(curve, tau)
    >>> np.round(ctrl, 9).tolist(), float(np.round(err, 9))
    ([1.0, 3.0], 0.0)
    """
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if q.ndim < 2 or q.shape[-1] != 2 or q.shape[-2] != tau.size or tau.size < 3:
        raise GeometryError(
            f"bezier_fit needs q (..., T, 2) with T = len(tau) >= 3, got {q.shape} and {tau.shape}"
        )
    a = ((1 - tau) ** 2)[:, None]
    w = (2 * tau * (1 - tau))[:, None]
    c = (tau**2)[:, None]
    q0 = q[..., :1, :]
    q1 = q[..., -1:, :]
    rest = q - a * q0 - c * q1
    ctrl = np.sum(w * rest, axis=-2) / float(np.sum(w**2))
    fitted = a * q0 + w * ctrl[..., None, :] + c * q1
    err = np.max(np.linalg.norm(fitted - q, axis=-1), axis=-1)
    return ctrl, err


def pack(q: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heat-map array ``(6, H, W)`` float32 and fit error ``(H, W)`` from ``q (H, W, T, 2)``."""
    ctrl, err = bezier_fit(q, tau)
    maps = np.concatenate([q[..., 0, :], q[..., -1, :], ctrl], axis=-1)
    return np.ascontiguousarray(np.moveaxis(maps, -1, 0), dtype=np.float32), err
