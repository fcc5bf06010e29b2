"""Splitting streaks that touch end to end.

On a dense grid, when a streak is about as long as the grid spacing, one dot's streak can end where
the next dot's begins: thresholding joins them into one straight-looking component. The centre-line
profile then dips between the two (two facing erf edges). A line much longer than the frame's
typical streak (``lines.long_factor`` times its median lit extent) whose profile falls below
``lines.gap_level`` of its plateau in its interior is cut at the dip. (All dots of a frame move
nearly alike, so the typical length is a good reference; a fast middle part of a single streak also
dims it, hence both tests.)
"""

from __future__ import annotations

import numpy as np

from blurtrack.detect.lines.centreline import RefinedLines
from blurtrack.detect.lines.ragged import Ragged, row_nanmedian, to_matrix
from blurtrack.detect.paramsections import LinesParams


def split_at_gaps(ref: RefinedLines, lp: LinesParams) -> tuple[RefinedLines, np.ndarray]:
    """Cut lines at interior profile gaps (``lp.gap_level``, ``lp.long_factor``); returns the
    new lines and, per new line, the index of the line it came from."""
    lens = ref.lines.sizes
    N = lens.size
    parent = np.arange(N)
    if N < 3:
        return ref, parent
    A = to_matrix(ref.profile, lens)
    cols = np.arange(A.shape[1])[None, :]
    valid = cols < lens[:, None]
    with np.errstate(all="ignore"):
        peak = A.max(axis=1)
        lit_vals = np.where(valid & (0.3 * peak[:, None] < A), A, np.nan)
        level = np.nan_to_num(row_nanmedian(lit_vals))
    lit = valid & (0.5 * level[:, None] <= A)
    has = lit.any(axis=1)
    first = np.argmax(lit, axis=1)
    last = A.shape[1] - 1 - np.argmax(lit[:, ::-1], axis=1)
    extent = np.where(has, (last - first) * ref.step, 0.0)
    typical = float(np.median(extent[has])) if np.any(has) else 0.0
    inner = (cols > first[:, None]) & (cols < last[:, None])
    gap = valid & (lp.gap_level * level[:, None] > A) & inner
    rows = np.flatnonzero(has & (extent > lp.long_factor * typical) & gap.any(axis=1))
    if rows.size == 0:
        return ref, parent
    starts = ref.lines.starts
    pieces: list[tuple[int, int, int]] = []  # (old line, first sample, last sample)
    cut_rows = set(rows.tolist())
    for i in range(N):
        if i not in cut_rows:
            pieces.append((i, 0, int(lens[i]) - 1))
            continue
        g = np.flatnonzero(gap[i])
        runs = np.split(g, np.flatnonzero(np.diff(g) > 1) + 1)
        cuts = [int(r[np.argmin(A[i, r])]) for r in runs if r.size]
        bounds = [0, *cuts, int(lens[i]) - 1]
        pieces += [(i, bounds[k], bounds[k + 1]) for k in range(len(bounds) - 1)]
    parent = np.array([pc[0] for pc in pieces])
    size = np.array([pc[2] - pc[1] + 1 for pc in pieces])
    src0 = np.array([starts[pc[0]] + pc[1] for pc in pieces])
    idx = np.repeat(src0 - np.concatenate(([0], np.cumsum(size)[:-1])), size) + np.arange(
        int(size.sum())
    )
    new = RefinedLines(
        lines=Ragged(ref.lines.points[idx], size),
        profile=ref.profile[idx],
        width=ref.width[parent],
        step=ref.step[parent],
    )
    return new, parent
