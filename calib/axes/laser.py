"""Axis discovery on laser sessions: streak time midpoints carried to the next frame.

Laser dots form a regular grid, and between frames the grid can move by more than half its
spacing, so dots cannot be paired from the images alone without aliasing by a grid cell. Each
candidate mapping ``P`` (and time shift) instead carries every midpoint ``m`` of frame ``a``
to frame ``a + 1`` with the gyro's rotation over the midpoint's own interval
(``t_m = T + exposure / 2 + readout · ȳ / H``, the same row in the next frame; DESIGN's
rolling shutter) and scores the median distance to the nearest midpoint there, capped at a
third of the dots' spacing: under the true mapping the prediction lands on the same dot
(sub-pixel), under a wrong one anywhere in the grid (about a quarter of the spacing). The
scan, ranking and refusals are :mod:`calib.axes.search`'s.

Speed (the search runs before every laser fit: ~120 time shifts, 24 candidates at each coarse
one): the gyro's rotation over each midpoint's interval comes from one orientation table of the
upsampled trace (:class:`OrientationTable`: cumulative products of each knot interval's
rotation, ``ω`` linear in between; a time inside an interval takes the partial step), two
look-ups per midpoint and shift instead of a ~1 ms sub-step integration, and closer to the
exact rotation than that; the 24 candidates' predictions are one batched evaluation ``P Mᵀ Pᵀ
b`` with ``Pᵀ b`` formed once (:func:`carried_px`); the capped nearest-midpoint distance is an
exact look-up in cells of twice the cap (:class:`CellIndex`), not a k-d tree query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.geometry.kernels import Mat3, matmul3, project_c, so3_exp_c, transpose3
from calib.axes.rotations import MIN_PAIRS, MIN_POINTS
from calib.axes.search import (
    COARSE_STEP_S,
    AxisSearch,
    proper_axis_permutations,
    ranked,
    scan_candidates,
)
from calib.errors import AxisSearchError, CalibError

#: Midpoints scored per candidate (a deterministic subsample beyond that).
MAX_POINTS = 1500
#: Frames are kept apart in one k-d tree by this row offset per frame index (px).
FRAME_STRIDE_PX = 1.0e5


@dataclass(frozen=True)
class OrientationTable:
    """IMU orientations ``Q(τ_k) = R(τ_0)ᵀ R(τ_k)`` at a trace's knots, for relative rotations
    ``R(t_a)ᵀ R(t_b) = Q(t_a)ᵀ Q(t_b)`` at any times.

    ``ω`` is linear between knots and held at the end samples' values beyond them (as
    ``np.interp`` holds it); each knot interval's rotation is the exponential of its integral
    (``h · (ω_k + ω_{k+1}) / 2``), and a time ``t`` inside ``[τ_k, τ_{k+1}]`` adds the partial
    step ``exp((t − τ_k) · ω((τ_k + t) / 2))``. Both are exact where ``ω`` keeps its direction.
    """

    t_s: np.ndarray
    omega_radps: np.ndarray  # (3, K)
    Q: np.ndarray  # (9, K) row-major components

    @classmethod
    def of(cls, gyro: GyroTrace, t0_s: float, t1_s: float) -> OrientationTable:
        """The table of ``gyro``'s knots over ``[t0_s, t1_s]`` (one knot beyond each end, and
        one second of held rate beyond the trace's ends)."""
        seg = gyro.segment(t0_s, t1_s)
        t = np.concatenate([[seg.t_s[0] - 1.0], seg.t_s, [seg.t_s[-1] + 1.0]])
        w = np.concatenate([seg.omega_radps[:1], seg.omega_radps, seg.omega_radps[-1:]])
        mean = (w[:-1] + w[1:]) / 2 * np.diff(t)[:, None]
        steps = np.stack(so3_exp_c(mean[:, 0], mean[:, 1], mean[:, 2]))
        return cls(t, np.ascontiguousarray(w.T), cumulative_products(steps))

    def at(self, t_s: np.ndarray) -> Mat3:
        """``Q(t)`` for times ``t_s`` (any shape) as a row-major 9-tuple."""
        k = np.clip(np.searchsorted(self.t_s, t_s, side="right") - 1, 0, self.t_s.size - 2)
        u = t_s - self.t_s[k]
        frac = 0.5 * u / (self.t_s[k + 1] - self.t_s[k])
        w = [(c[k] + (c[k + 1] - c[k]) * frac) * u for c in self.omega_radps]
        Qk: Mat3 = tuple(self.Q[i][k] for i in range(9))  # type: ignore[assignment]
        return matmul3(Qk, so3_exp_c(w[0], w[1], w[2]))

    def relative(self, t_a_s: np.ndarray, t_b_s: np.ndarray) -> Mat3:
        """``R(t_a)ᵀ R(t_b)`` (row-major 9-tuple of arrays shaped like the times)."""
        return matmul3(transpose3(self.at(t_a_s)), self.at(t_b_s))


def cumulative_products(steps: np.ndarray) -> np.ndarray:
    """``(9, M + 1)`` products ``E_0 E_1 … E_{k-1}`` (``I`` first) of rotation steps ``(9, M)``
    (row-major components), by ``log2 M`` vectorised doubling passes."""
    P = steps.copy()
    d = 1
    while d < P.shape[1]:
        left: Mat3 = tuple(P[:, :-d])  # type: ignore[assignment]
        right: Mat3 = tuple(P[:, d:])  # type: ignore[assignment]
        P[:, d:] = np.stack(matmul3(left, right))
        d *= 2
    return np.concatenate([np.eye(3).reshape(9, 1), P], axis=1)


def covered(gyro: GyroTrace, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``(N,)`` whether ``gyro`` covers each ``[lo, hi]`` (:meth:`GyroTrace.covers`, batched)."""
    t = gyro.t_s
    assert gyro.max_gap_s is not None
    gap = np.flatnonzero(np.diff(t) > gyro.max_gap_s)
    ok = (np.minimum(lo, hi) >= t[0]) & (np.maximum(lo, hi) <= t[-1])
    if gap.size:
        # the first gap ending after lo is the only one that can start before hi
        k = np.searchsorted(t[gap + 1], np.minimum(lo, hi), side="right")
        inside = k < gap.size
        ok[inside] &= ~(t[gap[k[inside]]] < np.maximum(lo, hi)[inside])
    return ok


class CellIndex:
    """Distance to the nearest of fixed points in the same frame, capped at ``cap``: exact,
    points binned by frame into square cells of side at least ``2 · cap``, so that every point
    within ``cap`` of a query lies in the 2 × 2 cells nearest it.

    The cells span the points' bounding box (and an empty border) in every frame; they grow
    (more points per cell, same answers) where that box would need more than
    :data:`MAX_CELLS` of them.
    """

    MAX_CELLS = 2_000_000

    def __init__(self, xy: np.ndarray, frame: np.ndarray, cap: float) -> None:
        self.cap = float(cap)
        self.f0 = int(frame.min())
        n_frames = self.n_frames = int(frame.max()) - self.f0 + 1
        self.lo = xy.min(axis=0)
        extent = np.maximum(xy.max(axis=0) - self.lo, 1e-9)
        side = max(2 * self.cap, float(np.sqrt(n_frames * np.prod(extent) / self.MAX_CELLS)))
        self.side = side
        # cells 1 .. n along each axis hold points; 0 and n + 1 are the empty border
        self.nx, self.ny = (int(e // side) + 3 for e in extent)
        key = self._cells(xy[:, 0], xy[:, 1], frame - self.f0)
        order = np.argsort(key, kind="stable")
        # sorted coordinates and one sentinel (index M) far from everything
        self.x = np.append(xy[order, 0], np.inf)
        self.y = np.append(xy[order, 1], np.inf)
        count = np.bincount(key, minlength=n_frames * self.nx * self.ny)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        self.first = np.where(count > 0, start, xy.shape[0])
        self.count = count
        self.depth = int(count.max())

    def _cells(self, x: np.ndarray, y: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Cell index of points (non-finite and outside: a border cell of frame ``f``)."""
        idx = []
        for v, lo, n in ((x, self.lo[0], self.nx), (y, self.lo[1], self.ny)):
            c = np.nan_to_num((v - lo) / self.side + 1, nan=0.0, posinf=n - 1, neginf=0.0)
            idx.append(np.clip(np.floor(c), 0, n - 1).astype(np.int64))
        return (f * self.ny + idx[1]) * self.nx + idx[0]

    def capped_distance(self, q: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """``min(distance to the nearest point of the same frame, cap)`` for queries ``q (M,
        2)`` in frames ``frame (M,)`` (the points' frames; non-finite queries: ``cap``)."""
        fin = np.all(np.isfinite(q), axis=1)
        x, y = np.where(fin, q[:, 0], 0.0), np.where(fin, q[:, 1], 0.0)
        if frame.size and not (frame.min() >= self.f0 and frame.max() < self.f0 + self.n_frames):
            raise CalibError("cell index: query frames must lie within the points' frames")
        # lower-left cell of the 2 x 2 around each query; clipped into the border beyond
        ll = self._cells(x - self.cap, y - self.cap, frame - self.f0)
        best = np.full(x.shape, self.cap)
        for off in (0, 1, self.nx, self.nx + 1):
            cell = np.minimum(ll + off, self.count.size - 1)
            i = self.first[cell]
            np.minimum(best, np.hypot(self.x[i] - x, self.y[i] - y), out=best)
            for k in range(1, self.depth):  # cells with more than one point (rare)
                sel = np.flatnonzero(self.count[cell] > k)
                if sel.size == 0:
                    break
                j = i[sel] + k
                d = np.hypot(self.x[j] - x[sel], self.y[j] - y[sel])
                best[sel] = np.minimum(best[sel], d)
        best[~fin] = self.cap
        return best


def carried_px(Mt: Mat3, back: np.ndarray, P: np.ndarray, camera: Camera) -> np.ndarray:
    """``(C, n, 2)`` pixels of bearings ``b`` carried by each candidate ``P (C, 3, 3)``:
    ``π(P Mᵀ Pᵀ b)``, given ``Pᵀ b`` as ``back (C, 3, n)`` and ``Mᵀ`` per bearing (row-major
    9-tuple of ``(n,)``)."""
    Z = np.stack([sum(Mt[3 * i + j] * back[:, j] for j in range(3)) for i in range(3)], axis=1)
    X = np.einsum("cij,cjn->icn", P, Z)
    u, v = project_c(X[0], X[1], X[2], camera.intrinsics, camera.dist)
    return np.stack([u, v], axis=-1)


def search_axes_laser(
    mid: np.ndarray,
    rows: np.ndarray,
    frame: np.ndarray,
    frame_t_s: np.ndarray,
    exposure_s: np.ndarray,
    camera: Camera,
    gyro: GyroTrace,
    shift0_s: float,
    window_s: float,
) -> AxisSearch:
    """Score the 24 proper axis permutations on midpoints (see the module docstring).

    Args:
        mid: ``(N, 2)`` streak time midpoints (px); ``rows``: ``(N,)`` rows dating them;
            ``frame``, ``frame_t_s``, ``exposure_s``: ``(N,)`` per streak, times relative to
            the gyro trace's origin (camera clock).
    """
    from scipy.spatial import cKDTree

    frame = np.asarray(frame, np.int64)
    nxt = np.isin(frame + 1, frame)
    counts = np.bincount(frame[nxt]) if np.any(nxt) else np.zeros(0, np.int64)
    pairs = np.flatnonzero(counts >= MIN_POINTS)
    src = np.flatnonzero(np.isin(frame, pairs))
    H = camera.height
    frames, first = np.unique(frame, return_index=True)
    nb = first[np.searchsorted(frames, frame[src] + 1)]
    # A midpoint's time, and that of the same row in the next frame (that frame's timing).
    ta = frame_t_s[src] + exposure_s[src] / 2 + camera.readout_s * rows[src] / H
    t_b = frame_t_s[nb] + exposure_s[nb] / 2 + camera.readout_s * rows[src] / H
    g = gyro.upsampled(GYRO_UPSAMPLE)
    ok = covered(g, ta + shift0_s - window_s, t_b + shift0_s + window_s)
    src, ta, t_b = src[ok], ta[ok], t_b[ok]
    n_pairs = np.unique(frame[src]).size
    if n_pairs < MIN_PAIRS:
        raise AxisSearchError(
            f"too few consecutive frame pairs with {MIN_POINTS}+ laser midpoints that the gyro "
            f"covers (± {window_s * 1e3:.0f} ms shift search): {n_pairs}, need {MIN_PAIRS}"
        )
    if src.size > MAX_POINTS:
        keep = np.sort(np.random.default_rng(0).choice(src.size, MAX_POINTS, replace=False))
        src, ta, t_b = src[keep], ta[keep], t_b[keep]
    own = np.stack([mid[:, 0], mid[:, 1] + FRAME_STRIDE_PX * frame], axis=1)
    spacing = float(np.median(cKDTree(own).query(own, k=2)[0][:, 1]))
    cap = spacing / 3
    cells = CellIndex(mid, frame, cap)
    table = OrientationTable.of(
        g,
        float(ta.min()) + shift0_s - window_s - COARSE_STEP_S,
        float(t_b.max()) + shift0_s + window_s + COARSE_STEP_S,
    )
    P = proper_axis_permutations()
    # Pᵀ b for every candidate, (24, 3, n): the shift-independent half of P Mᵀ Pᵀ b.
    back = np.einsum("cji,nj->cin", P, camera.unproject(mid[src]))
    target = frame[src] + 1

    def predict(shift: float, which: np.ndarray) -> np.ndarray:
        # Mᵀ = R(t_b)ᵀ R(t_a) on the IMU clock
        return carried_px(table.relative(t_b + shift, ta + shift), back[which], P[which], camera)

    def score(shift: float, which: np.ndarray) -> np.ndarray:
        q = predict(shift, which).reshape(-1, 2)
        d = cells.capped_distance(q, np.tile(target, which.size))
        return np.median(d.reshape(which.size, -1), axis=1)

    shifts, scores = scan_candidates(score, shift0_s, window_s)
    best = int(np.argmin(scores))
    q = predict(float(shifts[best]), np.array([best]))[0]
    motion = float(np.median(np.linalg.norm(q - mid[src], axis=1)))
    return ranked(shifts, scores, motion, int(n_pairs), "laser midpoints")
