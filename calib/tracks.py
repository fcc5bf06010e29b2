"""Inter-frame tracks: one laser dot's time midpoints in consecutive frames as a residual.

A streak's time midpoint ``m`` (the point that halves its light; light is proportional to
time) is where the dot was at the middle of its exposure: with ``t_s = T + readout · s_y / H``
and ``t_e = T + readout · e_y / H + exposure`` (DESIGN's row times),
``t_m = (t_s + t_e) / 2 = T + exposure / 2 + readout · ȳ / H`` with ``ȳ = (s_y + e_y) / 2``.
The same dot seen in the next frame has midpoint ``m'`` at ``t_m'``, and the pure-rotation
model must carry ``m`` from ``t_m`` to ``t_m'`` onto ``m'``. That is the endpoint residual of
:mod:`calib.problem` with ``start = m``, ``end = m'``, ``frame_t = T + exposure / 2``,
``exposure = t_m' - t_m`` minus the row terms, and the rows ``ȳ``, ``ȳ'`` dating the two points
(:attr:`calib.data.StreakSet.time_row`): a *pseudo-streak*, so every solver stage, the exact
Jacobian and the uncertainty work on tracks unchanged.

Why: a midpoint is an integral of the whole streak, so the estimator is hardly affected by what
biases detected ends (edge blur along the streak that differs from the cross-section's under a
rolling shutter, convex brightness at the ends, tilted end caps): those errors are equal and
opposite at the two ends of a streak and cancel in the midpoint. They do not cancel in a
streak's length, which is what fixes the focal lengths from endpoints, and a few hundredths of
a pixel there are a few tenths of a percent of focal length (docs/calibration.md). A track
also spans a whole frame period (33 ms at 30 fps against a 20 ms exposure) and does not depend
on which end is the start.

Association: each midpoint of frame ``f`` is predicted into the next frame present in the set
(at most :data:`MAX_FRAME_GAP` frames on) with the current parameters and paired with the
nearest midpoint there within ``gate_px``; a midpoint of the later frame claimed twice keeps
its closer partner only. Laser dots are tens of pixels apart, a calibrated prediction is good
to a fraction of a pixel, so the pairing is unambiguous.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import pairwise

import numpy as np
from scipy.spatial import cKDTree

from calib.data import StreakSet
from calib.errors import CalibError
from calib.problem import ResidualModel
from calib.solve import Evaluator

#: Association gate (px) between a predicted and a measured midpoint.
GATE_PX = 3.0
#: Largest frame-index step a track may bridge (a held-out or dropped frame in between).
MAX_FRAME_GAP = 2


def mean_rows(streaks: StreakSet) -> np.ndarray:
    """``(N,)`` mean row of each streak's two ends: the row that dates its time midpoint."""
    return (streaks.start[:, 1] + streaks.end[:, 1]) / 2


def _pseudo(
    streaks: StreakSet, a: np.ndarray, b: np.ndarray, end: np.ndarray, row_b: np.ndarray
) -> StreakSet:
    """Pseudo-streaks from midpoints ``a`` to frames ``b`` (see the module docstring)."""
    assert streaks.mid is not None
    ft = streaks.frame_t_s[a] + streaks.exposure_s[a] / 2
    ft_b = streaks.frame_t_s[b] + streaks.exposure_s[b] / 2
    rows = np.stack([mean_rows(streaks)[a], row_b], axis=1)
    return StreakSet(
        start=streaks.mid[a],
        end=end,
        frame_t_s=ft,
        exposure_s=ft_b - ft,
        frame=streaks.frame[a],
        streak_id=streaks.streak_id[a],
        t0_s=streaks.t0_s,
        time_row=rows,
    )


def build_tracks(
    model: ResidualModel | Evaluator,
    theta: np.ndarray,
    streaks: StreakSet,
    gate_px: float = GATE_PX,
) -> tuple[StreakSet, np.ndarray]:
    """Pair midpoints of consecutive frames under ``theta`` (see the module docstring),
    predicted by the per-streak model or an evaluator (the fit's grid: cheaper over a frame
    period).

    Returns the tracks as pseudo-streaks and ``(T, 2)`` indices into ``streaks`` of each
    track's earlier and later streak. Raises :class:`CalibError` when the streaks carry no
    midpoints.
    """
    if streaks.mid is None:
        raise CalibError(
            "inter-frame tracks need the streaks' time midpoints (the mid_x, "
            "mid_y columns that blurtrack detect writes)"
        )
    residual = model.residual_np if isinstance(model, ResidualModel) else model.residual
    frames = np.unique(streaks.frame)
    by_frame = {int(f): np.flatnonzero(streaks.frame == f) for f in frames}
    steps = [
        (by_frame[int(f)], by_frame[int(g)]) for f, g in pairwise(frames) if g - f <= MAX_FRAME_GAP
    ]
    src: list[np.ndarray] = []
    dst: list[np.ndarray] = []
    if steps:
        a = np.concatenate([ia for ia, _ in steps])
        b0 = np.concatenate([np.full(ia.size, ib[0]) for ia, ib in steps])
        # Predict each midpoint into the later frame; its row there is first guessed as its
        # own, then taken from the first prediction (one rolling-shutter fixed-point step is
        # ample: a row error of a pixel moves the time by readout / H).
        row = streaks.mid[a, 1]
        pred = streaks.mid[a]
        for _ in range(2):
            probe = _pseudo(streaks, a, b0, pred, row)
            pred = residual(theta, probe)[:, :2] + probe.end
            row = pred[:, 1]
        off = 0
        for idx_a, idx_b in steps:
            p = pred[off : off + idx_a.size]
            off += idx_a.size
            ok = np.all(np.isfinite(p), axis=1)
            if not np.any(ok):
                continue
            dist, j = cKDTree(streaks.mid[idx_b]).query(p[ok], distance_upper_bound=gate_px)
            hit = np.isfinite(dist)
            order = np.argsort(dist[hit])
            claimed = idx_b[j[hit]][order]
            # A later midpoint keeps its closest claimant (first in distance order).
            _, first = np.unique(claimed, return_index=True)
            src.append(idx_a[ok][hit][order][first])
            dst.append(claimed[first])
    P = (
        np.stack([np.concatenate(src), np.concatenate(dst)], axis=1).astype(np.int64)
        if src
        else np.zeros((0, 2), dtype=np.int64)
    )
    P = P[np.lexsort((P[:, 0], streaks.frame[P[:, 0]]))]
    tracks = _pseudo(streaks, P[:, 0], P[:, 1], streaks.mid[P[:, 1]], mean_rows(streaks)[P[:, 1]])
    return tracks, P


def concat(parts: list[StreakSet]) -> StreakSet:
    """One set from several (endpoint streaks and tracks): every set's time rows made
    explicit; centre lines and midpoints are dropped."""
    parts = [p for p in parts if len(p)]
    if not parts:
        raise CalibError("nothing to fit: no streaks and no tracks")
    if len(parts) == 1:
        return replace(parts[0], centre=None, mid=None, time_row=parts[0].rows)
    return StreakSet(
        start=np.concatenate([p.start for p in parts]),
        end=np.concatenate([p.end for p in parts]),
        frame_t_s=np.concatenate([p.frame_t_s for p in parts]),
        exposure_s=np.concatenate([p.exposure_s for p in parts]),
        frame=np.concatenate([p.frame for p in parts]),
        streak_id=np.concatenate([p.streak_id for p in parts]),
        t0_s=parts[0].t0_s,
        time_row=np.concatenate([p.rows for p in parts]),
    )
