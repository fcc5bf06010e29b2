"""Whether the lines measured on a frame confirm the gyro-predicted curves placed there
(the template pass's check, :mod:`blurtrack.detect.gyro.gyropass`): end-to-end mismatch either way
round, a line of the placed curve's shape slightly shifted along a chain, a placed curve cut
at the frame's border, and the frame's acceptance. Pixels as DESIGN's (``(0, 0)`` the centre
of the top-left pixel); ends ``(N, 2)``.
"""

from __future__ import annotations

import numpy as np


def accepted(confirmed: int, measured: int, accept_min: float) -> bool:
    """Whether a frame's placements fit the prior: at least ``accept_min``
    (``gyro_pass.accept_min``) of the
    ``measured`` placements ``confirmed`` in components replaced whole. A wrong prior (the
    rendered hairpins with the gyro's sign reversed) confirms 3 of 11; frames of long
    collinear chains confirm fewer than plain ones (hard seed 3 frame 6: 66 of 160, every
    other frame of seeds 1-3 0.80 or more), their other placements' lines running along the
    chain and dropped one by one (their components keep their first-pass lines)."""
    return confirmed >= accept_min * measured


def cut_at_border(curve: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """The ends of the part of ``curve (S, 2)`` inside the frame ``[0, W-1] x [0, H-1]`` (its
    longest run of samples inside, extended to where it crosses the border); the curve's
    own ends where it lies wholly inside (or wholly outside)."""
    ins = (curve[:, 0] >= 0) & (curve[:, 0] <= W - 1) & (curve[:, 1] >= 0) & (curve[:, 1] <= H - 1)
    if ins.all() or not ins.any():
        return curve[0], curve[-1]
    idx = np.flatnonzero(ins)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    i0, i1 = int(run[0]), int(run[-1])
    lo, hi = np.zeros(2), np.array([W - 1.0, H - 1.0])

    def cross(p_in: np.ndarray, p_out: np.ndarray) -> np.ndarray:
        d = p_out - p_in
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d < 0, (lo - p_in) / d, np.where(d > 0, (hi - p_in) / d, np.inf))
        return np.asarray(p_in + float(np.clip(np.min(t), 0.0, 1.0)) * d)

    s = cross(curve[i0], curve[i0 - 1]) if i0 > 0 else curve[i0]
    e = cross(curve[i1], curve[i1 + 1]) if i1 < len(curve) - 1 else curve[i1]
    return s, e


def mismatch(a: np.ndarray, b: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Orientation-free mean distance of ends ``a, b`` from ``s, e`` (all ``(N, 2)``)."""
    same = np.hypot(*(a - s).T) + np.hypot(*(b - e).T)
    swap = np.hypot(*(a - e).T) + np.hypot(*(b - s).T)
    return np.asarray(np.minimum(same, swap) / 2.0)


def confirmed(
    a: np.ndarray,
    b: np.ndarray,
    s: np.ndarray,
    e: np.ndarray,
    tol: np.ndarray,
    shape_shift_factor: float,
) -> np.ndarray:
    """Measured lines ``a, b`` that the placed curves' ends ``s, e`` confirm: within ``tol`` (either
    orientation), or of the same shape (the ends about their centre within ``tol``) within
    ``shape_shift_factor`` (``gyro_pass.shape_shift_factor``) times ``tol``. Along a collinear chain
    a placement may sit some px along the line from its dot (the neighbours' light fits it as well),
    while the line measured on its own image is the dot's (hard seed 3 frame 7: measured ends a
    median 1.0 px from the truth, the placed ones 7.9 px)."""
    mis = mismatch(a, b, s, e)
    cm, cp = 0.5 * (a + b), 0.5 * (s + e)
    shape = mismatch(a - cm, b - cm, s - cp, e - cp)
    return np.asarray((mis <= tol) | ((shape <= tol) & (mis <= shape_shift_factor * tol)))
