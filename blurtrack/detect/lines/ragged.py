"""Operations on batches of polylines stored ragged: one ``(M, 2)`` array plus sizes ``(N,)``.

A frame holds tens to hundreds of streaks; doing the per-streak geometry (smoothing, tangents,
resampling, extension) as whole-array numpy operations keeps the per-streak Python cost near
zero, which the detection speed target (60 frames/s at 1280x720 on one core) requires.
Every line must have at least 2 points.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from itertools import pairwise

import numpy as np


@dataclass(frozen=True)
class Ragged:
    """``points (M, 2)`` of N polylines; line ``i`` is ``points[starts[i]:starts[i] + sizes[i]]``.
    ``step``: per line the arc-length spacing of its points where known (after
    :func:`resample`), else None.
    """

    points: np.ndarray
    sizes: np.ndarray
    step: np.ndarray | None = None

    @cached_property
    def starts(self) -> np.ndarray:
        """First index of every line, ``(N,)`` (computed once per instance)."""
        return np.concatenate(([0], np.cumsum(self.sizes)[:-1])).astype(np.int64)

    @cached_property
    def line_of(self) -> np.ndarray:
        """Line index of every point, ``(M,)``."""
        return np.repeat(np.arange(self.sizes.size), self.sizes)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per point: first and last index of its line, ``(M,)`` each."""
        st = self.starts
        lo = np.repeat(st, self.sizes)
        return lo, lo + np.repeat(self.sizes, self.sizes) - 1

    def split(self) -> list[np.ndarray]:
        return split_at(self.points, np.cumsum(self.sizes)[:-1])

    @staticmethod
    def from_list(lines: list[np.ndarray]) -> Ragged:
        return Ragged(
            np.concatenate(lines).astype(np.float64),
            np.array([len(p) for p in lines], dtype=np.int64),
        )


def _norms(d: np.ndarray) -> np.ndarray:
    """Lengths ``(M,)`` of 2-D vectors ``(M, 2)`` (``np.linalg.norm(d, axis=1)``, faster)."""
    x, y = d[:, 0], d[:, 1]
    return np.sqrt(x * x + y * y)  # no overflow concern at pixel scales; hypot is 4x slower


def split_at(values: np.ndarray, cuts: np.ndarray) -> list[np.ndarray]:
    """``np.split(values, cuts)`` (views along the first axis) with plain slicing, which is
    several times faster for hundreds of pieces."""
    bounds = [0, *np.asarray(cuts).tolist(), values.shape[0]]
    return [values[a:b] for a, b in pairwise(bounds)]


def smooth(r: Ragged) -> Ragged:
    """Binomial [1 4 6 4 1]/16 smoothing within each line; beyond its ends a line is continued
    by point reflection through the end point, so straight lines and the end points of lines
    with 3 points or more are kept exactly."""
    p = r.points
    M = p.shape[0]
    out = np.empty_like(p)
    if M >= 5:  # one convolution for all lines; the 2 points next to every end are redone
        out[2:-2] = (p[:-4] + p[4:] + 4.0 * (p[1:-3] + p[3:-1]) + 6.0 * p[2:-2]) / 16.0
    st = r.starts
    en = st + r.sizes - 1
    big = r.sizes >= 4
    # Lines of 4 points or more: the reflection worked out (the ends stay where they are).
    sb, eb = st[big], en[big]
    out[sb] = p[sb]
    out[eb] = p[eb]
    out[sb + 1] = (6.0 * p[sb] + 5.0 * p[sb + 1] + 4.0 * p[sb + 2] + p[sb + 3]) / 16.0
    out[eb - 1] = (6.0 * p[eb] + 5.0 * p[eb - 1] + 4.0 * p[eb - 2] + p[eb - 3]) / 16.0
    if big.all():
        return Ragged(out, r.sizes)
    # Shorter lines (few): every point by explicit reflection, clamped to the line.
    small = np.flatnonzero(~big)
    near = np.concatenate([np.arange(st[i], en[i] + 1) for i in small.tolist()])
    line = np.repeat(small, r.sizes[small])
    lo, hi = st[line], en[line]
    acc = 6.0 * p[near]
    for off, w in ((-2, 1.0), (-1, 4.0), (1, 4.0), (2, 1.0)):
        j = near + off
        below, above = j < lo, j > hi
        src = np.clip(np.where(below, 2 * lo - j, np.where(above, 2 * hi - j, j)), lo, hi)
        q = p[src]
        q = np.where(below[:, None], 2 * p[lo] - q, q)
        q = np.where(above[:, None], 2 * p[hi] - q, q)
        acc += w * q
    out[near] = acc / 16.0
    return Ragged(out, r.sizes)


def tangents(r: Ragged) -> np.ndarray:
    """Unit tangents ``(M, 2)`` by central differences (one-sided at the ends)."""
    p = r.points
    d = np.empty_like(p)
    d[1:-1] = p[2:] - p[:-2]  # across line boundaries too: the ends are redone below
    st = r.starts
    en = st + r.sizes - 1
    d[st] = p[st + 1] - p[st]
    d[en] = p[en] - p[en - 1]
    return d / np.maximum(_norms(d), 1e-12)[:, None]


def arc_lengths(r: Ragged) -> tuple[np.ndarray, np.ndarray]:
    """Per point the arc length from its line's start ``(M,)``; per line the total ``(N,)``."""
    seg = _norms(np.diff(r.points, axis=0))
    ends = np.cumsum(r.sizes)[:-1] - 1  # last point of every line but the last
    seg[ends] = 0.0
    cs = np.concatenate(([0.0], np.cumsum(seg)))
    st = r.starts
    s = cs - np.repeat(cs[st], r.sizes)
    total = s[st + r.sizes - 1]
    return s, total


def resample(r: Ragged, step: float = 1.0) -> Ragged:
    """Resample every line at constant arc-length spacing close to ``step`` px, ends kept.

    A line of length L gets ``round(L / step) + 1`` points (at least 2); zero-length lines
    become two coincident points.
    """
    s, total = arc_lengths(r)
    n_new = np.maximum(np.rint(total / step).astype(np.int64), 1) + 1
    line_new = np.repeat(np.arange(n_new.size), n_new)
    j = np.arange(line_new.size) - np.repeat(np.concatenate(([0], np.cumsum(n_new)[:-1])), n_new)
    u = j * np.repeat(total / (n_new - 1), n_new)
    # One global search: shift each line's arc lengths past the previous lines'.
    shift = np.concatenate(([0.0], np.cumsum(total + 1.0)[:-1]))
    key = s + np.repeat(shift, r.sizes)
    k = np.searchsorted(key, u + shift[line_new], side="right") - 1
    st = r.starts
    k = np.clip(k, st[line_new], st[line_new] + r.sizes[line_new] - 2)
    ds = s[k + 1] - s[k]
    f = np.where(ds > 0, (u - s[k]) / np.where(ds > 0, ds, 1.0), 0.0)
    f = np.clip(f, 0.0, 1.0)[:, None]
    pts = r.points[k] * (1 - f) + r.points[k + 1] * f
    return Ragged(pts, n_new, total / (n_new - 1))


def extend(r: Ragged, n_ext: int, span: int = 3) -> Ragged:
    """Extend both ends of every (uniformly sampled) line straight by ``n_ext`` points, at the
    line's own mean spacing (its resampling step where known), along the direction of its last
    ``span`` points."""
    if r.step is not None:
        spacing = r.step
    else:
        _, total = arc_lengths(r)
        spacing = np.where(r.sizes > 1, total / np.maximum(r.sizes - 1, 1), 1.0)
    spacing = np.where(spacing > 1e-9, spacing, 1.0)
    st = r.starts
    en = st + r.sizes - 1
    p = r.points
    d_tail = p[en] - p[np.maximum(en - span, st)]
    d_head = p[st] - p[np.minimum(st + span, en)]
    d_tail /= np.maximum(_norms(d_tail), 1e-12)[:, None]
    d_head /= np.maximum(_norms(d_head), 1e-12)[:, None]
    zero = _norms(p[en] - p[st]) < 1e-9  # round spots: any axis
    d_tail[zero] = [1.0, 0.0]
    d_head[zero] = [-1.0, 0.0]
    steps = np.arange(1, n_ext + 1, dtype=np.float64)
    d_head *= spacing[:, None]
    d_tail *= spacing[:, None]
    head = p[st][:, None, :] + d_head[:, None, :] * steps[::-1][None, :, None]
    tail = p[en][:, None, :] + d_tail[:, None, :] * steps[None, :, None]
    N = r.sizes.size
    sizes = r.sizes + 2 * n_ext
    out = np.empty((int(sizes.sum()), 2))
    new_st = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    body_idx = np.repeat(new_st + n_ext - st, r.sizes) + np.arange(p.shape[0])
    out[body_idx] = p
    ext_idx = new_st[:, None] + np.arange(n_ext)[None, :]
    out[ext_idx.ravel()] = head.reshape(N * n_ext, 2)
    tail_idx = (new_st + n_ext + r.sizes)[:, None] + np.arange(n_ext)[None, :]
    out[tail_idx.ravel()] = tail.reshape(N * n_ext, 2)
    return Ragged(out, sizes)


def to_matrix(values: np.ndarray, sizes: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Pad ragged scalars ``(M,)`` into ``(N, max(sizes))`` rows."""
    N = sizes.size
    L = int(sizes.max()) if N else 0
    out = np.full((N, L), fill, dtype=np.float64)
    st = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    j = np.arange(values.size) - np.repeat(st, sizes)
    out[np.repeat(np.arange(N), sizes), j] = values
    return out


def cut(r: Ragged, keep: np.ndarray) -> Ragged:
    """Keep, per line, the points from its first to its last ``keep`` point (``keep (M,)``);
    lines with fewer than 2 such points are left whole."""
    idx = np.arange(r.points.shape[0])
    st = r.starts
    big = r.points.shape[0]
    first = np.minimum.reduceat(np.where(keep, idx, big), st)
    last = np.maximum.reduceat(np.where(keep, idx, -1), st)
    whole = last - first < 1
    first = np.where(whole, st, first)
    last = np.where(whole, st + r.sizes - 1, last)
    line = r.line_of
    sel = (idx >= first[line]) & (idx <= last[line])
    return Ragged(r.points[sel], last - first + 1)


def row_nanmedian(X: np.ndarray) -> np.ndarray:
    """``np.nanmedian(X, axis=1)`` of a 2-D array without its warnings and its slow masked
    path for short rows: one row-wise sort (NaNs sort last) and the middle of the valid part;
    nan for rows without a valid value."""
    N = X.shape[0]
    if N == 0 or X.shape[1] == 0:
        return np.full(N, np.nan)
    S = np.sort(X, axis=1)
    n = np.count_nonzero(~np.isnan(X), axis=1)
    rows = np.arange(N)
    lo = np.maximum((n - 1) // 2, 0)
    med = 0.5 * (S[rows, lo] + S[rows, np.maximum(n // 2, 0)])
    return np.where(n > 0, med, np.nan)
