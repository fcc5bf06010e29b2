"""References for template separation from whole *components*
(:mod:`blurtrack.detect.separation.separate`).

Separation needs a few whole, isolated streaks as templates. On a frame whose streaks are curved
(the "2"-shaped trails of real point lights under hand shake) the first pass breaks most of them at
their hooks, so its lines give too few references. The components of the thresholded image do not
depend on that: an isolated light is one component, and every light drew the same curve, so isolated
lights are components of nearly equal area and extent. The *modal* cluster of components (the one
with the most members within ``separation.modal_cluster_log`` of one another in log area, log width
and log height, away from the border) is taken as the frame's whole streaks; each member's centre
line is the longest path of its skeleton (:func:`skeleton_path`; the first pass's lines of these
components are broken or cut short), measured on the frame like a first-pass line; their
start-to-end vectors give the consensus field and the references.
"""

from __future__ import annotations

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.lines.measure import LineSet, Measured, measure_lines
from blurtrack.detect.lines.segment import Components
from blurtrack.detect.paramsections import SeparationParams
from blurtrack.detect.separation.consensus import Consensus, consensus_field


def modal_components(comps: Components, away: np.ndarray, sp: SeparationParams) -> np.ndarray:
    """``(C,)`` bool: the modal cluster of components (see the module text) among ``away``
    (those that do not touch the border; at least ``sp.modal_min_area_px``); all False when
    it has under two members."""
    C = comps.ids.size
    out = np.zeros(C, bool)
    idx = np.flatnonzero(away & (comps.areas >= sp.modal_min_area_px))
    if idx.size < 2:
        return out
    f = np.log(
        np.column_stack([comps.areas[idx], comps.boxes[idx, 2], comps.boxes[idx, 3]]).astype(
            np.float64
        )
    )
    d = np.max(np.abs(f[:, None, :] - f[None, :, :]), axis=2)
    near = d <= sp.modal_cluster_log
    count = near.sum(axis=1)
    # Ties go to the larger components (fragments of a streak are smaller, chains larger and
    # rarer).
    best = int(np.lexsort((-comps.areas[idx], -count))[0])
    centre = np.median(f[near[best]], axis=0)
    members = np.max(np.abs(f - centre), axis=1) <= sp.modal_cluster_log
    if int(members.sum()) >= 2:
        out[idx[members]] = True
    return out


def _bfs(adj: list[list[int]], start: int) -> tuple[np.ndarray, np.ndarray]:
    dist = np.full(len(adj), -1, np.int64)
    prev = np.full(len(adj), -1, np.int64)
    dist[start] = 0
    queue = [start]
    for i in queue:
        for j in adj[i]:
            if dist[j] < 0:
                dist[j] = dist[i] + 1
                prev[j] = i
                queue.append(j)
    return dist, prev


def skeleton_path(mask: np.ndarray) -> np.ndarray:
    """The longest path (in skeleton steps) of the skeleton of a component ``mask``: ``(n, 2)``
    pixel centres x, y in the mask's coordinates, in order (two breadth-first searches: from
    any point to the farthest, and from there to the farthest again)."""
    from skimage.morphology import skeletonize  # lazy: a slow import

    sk = skeletonize(np.pad(mask, 1))
    ys, xs = np.nonzero(sk)
    if ys.size < 2:
        return np.column_stack([xs, ys]).astype(np.float64) - 1.0
    index = -np.ones(sk.shape, np.int64)
    index[ys, xs] = np.arange(ys.size)
    adj: list[list[int]] = [[] for _ in range(ys.size)]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx or dy:
                nb = index[ys + dy, xs + dx]
                for i in np.flatnonzero(nb >= 0).tolist():
                    adj[i].append(int(nb[i]))
    dist, _ = _bfs(adj, 0)
    a = int(np.argmax(dist))
    dist, prev = _bfs(adj, a)
    node = int(np.argmax(dist))
    path = [node]
    while prev[node] >= 0:
        node = int(prev[node])
        path.append(node)
    return np.column_stack([xs[path], ys[path]]).astype(np.float64) - 1.0


def component_references(
    ctx: FrameContext, sigma_c: float, sigma_raw: float
) -> tuple[Measured, Consensus] | None:
    """The modal components' joined lines, measured on the frame, and the consensus field of
    their start-to-end vectors (None: fewer than ``quality.min_reference`` of them);
    ``sigma_c``, ``sigma_raw``: the first pass's cross-section sigmas (smoothed, raw)."""
    comps, q = ctx.comps, ctx.params.quality
    min_ref = q.min_reference
    H, W = ctx.shape
    x, y, w, h = comps.boxes.T
    away = (x > 0) & (y > 0) & (x + w < W) & (y + h < H)
    modal = modal_components(comps, away, ctx.params.separation)
    if int(modal.sum()) < min_ref:
        return None
    lines: list[np.ndarray] = []
    owner: list[int] = []
    for ci in np.flatnonzero(modal).tolist():
        bx, by, bw, bh = (int(t) for t in comps.boxes[ci])
        path = skeleton_path(comps.labels[by : by + bh, bx : bx + bw] == comps.ids[ci])
        if len(path) >= 2:
            lines.append(path + np.array([bx, by], np.float64))
            owner.append(ci)
    if len(lines) < min_ref:
        return None
    n = len(lines)
    ls = LineSet(lines, owner, [False] * n, [False] * n)
    m = measure_lines(ctx, ls, sigma_c, False, sigma_raw)
    if len(m) < min_ref:
        return None
    field = consensus_field(m.end_b - m.end_a, m.time_mid, np.ones(len(m), bool), q)
    return None if field is None else (m, field)
