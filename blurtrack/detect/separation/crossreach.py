"""Which ends of a crossing streak another streak's light reaches (issue 45).

A crossing is a doubt about an end only where the other streak's light enters what that end's
fit reads. The profile is the cross-section integral over ``ceil(3 sigma) + 1`` px either side
of the centre line (:func:`blurtrack.detect.lines.centreline.refine_lines`), and another
streak's light reaches ``3 sigma`` from its own centre line, so its light enters this streak's
profile where the two centre lines come within :func:`light_radius` ``= ceil(3 sigma) + 1 +
3 sigma``. An end's edge fit (:func:`blurtrack.detect.lines.endpoints.rising_edges`) reads from
``3 sigma + 1`` samples beyond the end (about 1 px each) to the end of its plateau window,
``PLATEAU_INSET_SIGMAS sigma + PLATEAU_WINDOW - 1`` samples inside (the end lies at the
half-level crossing); a short streak's moments read the whole profile, both ends alike.

Measured on the hard preset's tuning seeds (1, 2, 5, 6; 8 frames; 650 streaks refused as
``crossing``): 4 crossings lay beyond both ends' reach; in the rest another streak's light
reached an end (one end: 398, both: 346). Where it reached one end, that end's error was
within 2 px for 80 % of them and the other end's for 92 %: such a crossing is the doubt about
the end it reaches, the same doubt as light beyond that end (``end_light``).
"""

from __future__ import annotations

import numpy as np

from blurtrack.detect.lines.endpoints import PLATEAU_INSET_SIGMAS, PLATEAU_WINDOW


def light_radius(sigma: float) -> float:
    """Centre-line distance (px) within which another streak's light enters a profile:
    the profile's cross-section half-width ``ceil(3 sigma) + 1`` plus ``3 sigma``."""
    return float(np.ceil(3.0 * sigma) + 1.0 + 3.0 * sigma)


def end_reach(sigma: float) -> tuple[float, float]:
    """How far (px) an end's edge fit reads: beyond the end ``3 sigma + 1`` and inside
    ``PLATEAU_INSET_SIGMAS sigma + PLATEAU_WINDOW - 1``."""
    return 3.0 * sigma + 1.0, PLATEAU_INSET_SIGMAS * sigma + PLATEAU_WINDOW - 1.0


def _arc(p: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])


def _beyond(p: np.ndarray, at_start: bool, out: float) -> np.ndarray:
    """Points on the extension of centre line ``p`` past its first (or last) point, up to
    ``out`` px, along the direction of its outermost ~3 px."""
    q = p if at_start else p[::-1]
    u = q[0] - q[min(3, len(q) - 1)]
    norm = float(np.hypot(*u))
    if norm == 0.0:
        return q[:1]
    return np.asarray(q[0] + np.outer(np.linspace(0.0, out, 8), u / norm))


def crossing_ends(
    points: list[np.ndarray], which: np.ndarray, sigma: float, short: np.ndarray | None
) -> np.ndarray:
    """``(N, 2)`` bool: for the streaks ``which`` (``(N,)``), whether another streak's light
    (another of ``points``, the frames' centre lines from end A to end B) reaches the light
    that end A / end B's fit reads (module docstring; ``sigma``: the frame's cross-section
    sigma). ``short``: ``(N,)`` the streaks whose ends came from the moments of the whole
    profile (any light along them reaches both ends); None: all of them."""
    n = len(points)
    out = np.zeros((n, 2), bool)
    idx = np.flatnonzero(which)
    if idx.size == 0 or n < 2:
        return out
    r = light_radius(sigma)
    beyond, inside = end_reach(sigma)
    moments = np.ones(n, bool) if short is None else np.asarray(short, bool)
    # Bounding boxes, grown by what can reach: only neighbours whose boxes meet are compared.
    lo = np.array([p.min(axis=0) if len(p) else np.full(2, np.inf) for p in points])
    hi = np.array([p.max(axis=0) if len(p) else np.full(2, -np.inf) for p in points])
    grow = r + beyond

    def lit_by_other(k: int, queries: list[np.ndarray]) -> list[np.ndarray]:
        """Per point set of ``queries``, ``(len(q),)`` whether another streak's centre line
        lies within ``r`` of each point: the neighbours whose grown boxes meet streak ``k``'s,
        their points in one array and every query point against them at once."""
        meet = np.all((lo <= hi[k] + grow) & (hi >= lo[k] - grow), axis=1)
        meet[k] = False
        sizes = [len(q) for q in queries]
        near = np.flatnonzero(meet).tolist()
        if not near:
            return [np.zeros(n, bool) for n in sizes]
        others = np.concatenate([points[j] for j in near])
        q = np.concatenate(queries)
        dx = q[:, 0, None] - others[None, :, 0]
        dy = q[:, 1, None] - others[None, :, 1]
        hit = np.any(dx * dx + dy * dy <= r * r, axis=1)
        return np.split(hit, np.cumsum(sizes)[:-1])

    for k in idx.tolist():
        p = points[k]
        if len(p) == 0:
            continue
        near, past_a, past_b = lit_by_other(
            k, [p, _beyond(p, True, beyond), _beyond(p, False, beyond)]
        )
        s = _arc(p)
        for end, past in ((0, past_a), (1, past_b)):
            read = s <= inside if end == 0 else s >= s[-1] - inside
            out[k, end] = bool(np.any(near & read)) or bool(np.any(past))
        if moments[k] and (near.any() or out[k].any()):
            out[k] = True
    return out
