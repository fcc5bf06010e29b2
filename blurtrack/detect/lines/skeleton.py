"""Ordered centre lines of folded components (S-curves, loops, crossings) from skeletons.

The component mask is thinned (scikit-image), the skeleton is cut into edges between nodes
(ends and junctions), short spurs are pruned and nearby junctions merged, and at every
junction the incident edges are paired by straightest continuation: a streak crossing itself
(a loop) or another streak goes straight through the crossing. Each chain of paired edges is
one streak. Pixel walks are plain Python, which is fine here: only folded components come
this way, and their skeletons are a few hundred pixels at most.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# 8-neighbour offsets in circular order (for the crossing number).
_RING = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))


@dataclass(frozen=True)
class TracedPath:
    """One streak found in a folded component.

    - ``points``: ``(n, 2)`` ordered (x, y) skeleton points, in the coordinates of the mask.
    - ``shares_junction``: the path meets another path of the same component (a crossing).
    - ``self_crossing``: the path passes through one junction twice (a loop).
    """

    points: np.ndarray
    shares_junction: bool
    self_crossing: bool


def _neighbours(skel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skeleton pixel coordinates ``(K, 2)`` (y, x), neighbour table ``(K, 8)`` (-1 = none) and
    the crossing number per pixel (0->1 transitions around the ring)."""
    ys, xs = np.nonzero(skel)
    index = np.full((skel.shape[0] + 2, skel.shape[1] + 2), -1, dtype=np.int64)
    index[ys + 1, xs + 1] = np.arange(ys.size)
    nb = np.stack([index[ys + 1 + dy, xs + 1 + dx] for dy, dx in _RING], axis=1)
    on = nb >= 0
    crossings = np.sum(on & ~np.roll(on, 1, axis=1), axis=1)
    return np.stack([ys, xs], axis=1), nb, crossings


def _walk(
    start: int,
    first: int,
    nb: list[list[int]],
    is_node: list[bool],
    visited: list[bool],
    yx: list[tuple[int, int]],
) -> list[int]:
    """Follow the skeleton from node pixel ``start`` through ``first`` to the next node pixel.

    Plain Python lists and ints on purpose: per-pixel numpy calls would cost far more."""
    path = [start, first]
    prev, cur = start, first
    while not is_node[cur]:
        visited[cur] = True
        cand = [c for c in nb[cur] if c != prev and (is_node[c] or not visited[c])]
        if not cand:
            break  # dead end without an end node (should not happen on a thinned skeleton)
        nodes = [c for c in cand if is_node[c] and (c != start or len(path) > 3)]
        if nodes:
            path.append(nodes[0])
            break
        if len(cand) > 1:
            # Staircases give two candidates; take the one farthest from prev, consume both.
            py, px = yx[prev]
            nxt = max(cand, key=lambda c: (yx[c][0] - py) ** 2 + (yx[c][1] - px) ** 2)
            for c in cand:
                if not is_node[c]:
                    visited[c] = True
        else:
            nxt = cand[0]
        prev, cur = cur, nxt
        path.append(cur)
    return path


def trace_paths(mask: np.ndarray, spur_px: float, merge_px: float) -> list[TracedPath]:
    """Split a folded component into ordered streak paths.

    Args:
        mask: ``(h, w)`` bool component mask (one connected component).
        spur_px: end branches shorter than this are pruned as thinning artefacts.
        merge_px: junctions closer than this along the skeleton are merged into one crossing.
    Returns:
        The paths, longest first (empty if the skeleton is degenerate).
    """
    from skimage.morphology import skeletonize  # only folded streaks need it (slow import)

    skel = skeletonize(mask)
    yx, nb, crossings = _neighbours(skel)
    K = yx.shape[0]
    if K < 2:
        return []
    degree = np.sum(nb >= 0, axis=1)
    is_node = (crossings >= 3) | (degree <= 1) | (crossings == 1) & (degree <= 2)
    nbl = [[c for c in row if c >= 0] for row in nb.tolist()]
    node = is_node.tolist()
    yxl = [tuple(p) for p in yx.tolist()]
    # Group adjacent node pixels (junction clusters) into nodes.
    node_of_l = [-1] * K
    n_nodes = 0
    node_idx = [k for k in range(K) if node[k]]
    for k in node_idx:
        if node_of_l[k] >= 0:
            continue
        stack = [k]
        node_of_l[k] = n_nodes
        while stack:
            c = stack.pop()
            for m in nbl[c]:
                if node[m] and node_of_l[m] < 0:
                    node_of_l[m] = n_nodes
                    stack.append(m)
        n_nodes += 1
    visited = [False] * K
    edges: list[list[int]] = []
    for k in node_idx:
        for m in nbl[k]:
            if visited[m] or (node[m] and node_of_l[m] == node_of_l[k]):
                continue
            if node[m]:  # two different nodes touching: a one-step edge
                if k < m:
                    edges.append([k, m])
                continue
            edges.append(_walk(k, m, nbl, node, visited, yxl))
    node_of = np.asarray(node_of_l, dtype=np.int64)
    if not edges:  # a closed ring without any node: cut it anywhere
        order = _walk(0, nbl[0][0], nbl, [False] * K, visited, yxl)
        return [TracedPath(yx[order][:, ::-1].astype(np.float64), False, False)]
    return _chain(edges, node_of, yx, spur_px, merge_px)


def _chain(
    edges: list[list[int]], node_of: np.ndarray, yx: np.ndarray, spur_px: float, merge_px: float
) -> list[TracedPath]:
    """Prune spurs, merge close junctions, pair edge ends at junctions and chain the edges."""
    ends = [[int(node_of[e[0]]), int(node_of[e[-1]])] for e in edges]
    # Arc length per edge: the steps of all edges in one pass (rows stepping from one edge
    # into the next are never summed), each edge's own steps summed as a contiguous slice.
    flat = yx[np.concatenate(edges)].astype(np.float64)
    step = np.linalg.norm(np.diff(flat, axis=0), axis=1)
    first = np.cumsum([0] + [len(e) for e in edges[:-1]])
    lengths = [float(np.sum(step[a : a + len(e) - 1])) for a, e in zip(first, edges, strict=True)]
    alive = [True] * len(edges)

    def degrees() -> dict[int, int]:
        deg: dict[int, int] = {}
        for i, (a, b) in enumerate(ends):
            if alive[i]:
                deg[a] = deg.get(a, 0) + 1
                deg[b] = deg.get(b, 0) + 1
        return deg

    for _ in range(2):  # prune spurs: short edges hanging off a junction
        deg = degrees()
        for i, (a, b) in enumerate(ends):
            if (
                alive[i]
                and lengths[i] < spur_px
                and a != b
                and min(deg[a], deg[b]) == 1
                and max(deg[a], deg[b]) >= 3
            ):
                alive[i] = False
                deg[a] -= 1
                deg[b] -= 1
    # Merge junction pairs joined by a short edge (an X crossing thins into two Y junctions).
    deg = degrees()
    parent = list(range(int(node_of.max()) + 1))

    def find(n: int) -> int:
        while parent[n] != n:
            n = parent[n]
        return n

    for i, (a, b) in enumerate(ends):
        if alive[i] and a != b and lengths[i] < merge_px and deg[a] >= 3 and deg[b] >= 3:
            alive[i] = False
            parent[find(a)] = find(b)
    ends = [[find(a), find(b)] for a, b in ends]
    # Edge ends per node, with the outgoing direction a few px along the edge.
    incident: dict[int, list[tuple[int, int, np.ndarray]]] = {}
    for i, e in enumerate(edges):
        if not alive[i]:
            continue
        pts = yx[e].astype(np.float64)
        look = min(len(pts) - 1, 6)
        for side in (0, 1):
            p = pts if side == 0 else pts[::-1]
            d = p[look] - p[0]
            d /= max(float(np.linalg.norm(d)), 1e-9)
            incident.setdefault(ends[i][side], []).append((i, side, d))
    partner: dict[tuple[int, int], tuple[int, int]] = {}
    node_degree = {n: len(v) for n, v in incident.items()}
    for items in incident.values():
        pairs = sorted(
            (float(items[a][2] @ items[b][2]), a, b)
            for a in range(len(items))
            for b in range(a + 1, len(items))
        )
        used: set[int] = set()
        for cos, a, b in pairs:
            if a in used or b in used or (cos > -0.3 and len(items) > 2):
                continue
            used.update((a, b))
            partner[items[a][:2]] = items[b][:2]
            partner[items[b][:2]] = items[a][:2]
    used_edges: set[int] = set()
    chains: list[tuple[list[int], list[int]]] = []  # (pixel indices, junction nodes passed)

    def follow(i: int, side: int) -> tuple[list[int], list[int]]:
        pix: list[int] = []
        passed: list[int] = []
        while i not in used_edges:
            used_edges.add(i)
            e = edges[i] if side == 0 else edges[i][::-1]
            pix.extend(e if not pix else e[1:])
            node = ends[i][1 - side]
            nxt = partner.get((i, 1 - side))
            if nxt is None:
                break
            if node_degree.get(node, 0) >= 3:
                passed.append(node)
            i, side = nxt
        return pix, passed

    for i in range(len(edges)):  # start at free ends first, then close the remaining cycles
        for side in (0, 1):
            if alive[i] and i not in used_edges and (i, side) not in partner:
                chains.append(follow(i, side))
    for i in range(len(edges)):
        if alive[i] and i not in used_edges:
            chains.append(follow(i, 0))
    node_users: dict[int, int] = {}
    for _, passed in chains:
        for n in set(passed):
            node_users[n] = node_users.get(n, 0) + 1
    paths = [
        TracedPath(
            points=yx[pix][:, ::-1].astype(np.float64),
            shares_junction=any(node_users[n] > 1 for n in passed),
            self_crossing=len(passed) != len(set(passed)),
        )
        for pix, passed in chains
        if len(pix) >= 2
    ]
    paths.sort(key=lambda p: -len(p.points))
    return paths
