"""Each placement's own image, tiled into one mosaic: the frame less the templates of the other
placements that overlap it (the measurement of separation's and the gyro-template pass's
placements, :mod:`blurtrack.detect.separation.separate`, :mod:`blurtrack.detect.gyro.gyromeasure`),
and which placements overlap (``crossing``)."""

from __future__ import annotations

import numpy as np

from blurtrack.detect.separation.templates import Placement, warp


def overlapping_placements(pl: list[Placement], overlap_fraction: float) -> np.ndarray:
    """``(P,)`` bool: the placement's support shares more than ``overlap_fraction`` of its
    pixels with another placement's."""
    P = len(pl)
    flag = np.zeros(P, bool)
    org = np.array([[p.tpl.box[0], p.tpl.box[1]] for p in pl]) + np.rint([p.shift for p in pl])
    size = np.array([[p.tpl.box[2], p.tpl.box[3]] for p in pl])
    end = org + size
    boxes_meet = np.all(
        (np.maximum(org[:, None], org[None]) < np.minimum(end[:, None], end[None])), axis=2
    )
    for i, j in zip(*np.nonzero(np.triu(boxes_meet, 1)), strict=True):
        lo = np.maximum(org[i], org[j]).astype(int)
        hi = np.minimum(end[i], end[j]).astype(int)
        oi, oj = (lo - org[i]).astype(int), (lo - org[j]).astype(int)
        ext = hi - lo
        si = pl[i].tpl.support[oi[1] : oi[1] + ext[1], oi[0] : oi[0] + ext[0]]
        sj = pl[j].tpl.support[oj[1] : oj[1] + ext[1], oj[0] : oj[0] + ext[0]]
        shared = float(np.sum(si * sj))
        if shared > overlap_fraction * min(pl[i].tpl.area, pl[j].tpl.area):
            flag[i] = flag[j] = True
    return flag


def placement_mosaic(
    smooth: np.ndarray, signal: np.ndarray, pl: list[Placement], pad: int
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """Each placement's own image (the frame minus the other placements' templates) tiled
    into one mosaic, ``pad`` px of zeros around each; returns the smoothed and raw mosaics,
    the placed lines in mosaic coordinates and per placement the offset from mosaic back to
    frame coordinates. (The mosaics clipped at zero in place are the own images with no
    pixel below zero: where the neighbours' templates cover more than the light, and where
    the background-subtracted frame itself is below zero.)

    Each neighbour's template is warped to its sub-pixel place and scaled by its amplitude
    once, onto its own tile of ``(h + 1, w + 1)`` px (as
    :func:`blurtrack.detect.separation.refit.refit` paints it), and subtracted from every
    placement's own image it reaches at an integer offset: the same values as warping it
    onto each own image's whole box (a translation's fractional part and hence its
    interpolation weights do not depend on the integer part), at a fraction of the pixels."""
    H, W = smooth.shape
    boxes = []
    for p in pl:
        x, y, w, h = p.tpl.box
        ox, oy = int(np.floor(x + p.shift[0])) - pad, int(np.floor(y + p.shift[1])) - pad
        boxes.append((ox, oy, w + 2 * pad + 1, h + 2 * pad + 1))
    width = max(1024, max(b[2] for b in boxes))
    tiles: list[tuple[int, int]] = []
    cx = cy = row_h = 0
    for b in boxes:  # shelf packing, ``pad`` of zeros between tiles
        if cx + b[2] > width:
            cx, cy, row_h = 0, cy + row_h + pad, 0
        tiles.append((cx, cy))
        cx += b[2] + pad
        row_h = max(row_h, b[3])
    mos_s = np.zeros((cy + row_h, width), np.float32)
    mos_r = np.zeros((cy + row_h, width), np.float32)
    lines: list[np.ndarray] = []
    back = np.zeros((len(pl), 2))
    # Which templates reach into which placement's box (the others cannot matter there).
    org = np.array([b[:2] for b in boxes], float)
    end = org + np.array([b[2:] for b in boxes], float)
    t_org = np.array([[p.tpl.box[0], p.tpl.box[1]] for p in pl]) + np.floor([p.shift for p in pl])
    t_end = t_org + np.array([[p.tpl.box[2] + 1, p.tpl.box[3] + 1] for p in pl])
    meet = np.all(
        np.maximum(org[:, None], t_org[None]) < np.minimum(end[:, None], t_end[None]), axis=2
    )
    np.fill_diagonal(meet, False)
    placed: dict[int, tuple[int, int, np.ndarray, np.ndarray]] = {}  # warped neighbour tiles
    shifts = [(float(p.shift[0]), float(p.shift[1])) for p in pl]
    for k, (p, (ox, oy, bw, bh), (tx, ty)) in enumerate(zip(pl, boxes, tiles, strict=True)):
        fx0, fy0, fx1, fy1 = max(ox, 0), max(oy, 0), min(ox + bw, W), min(oy + bh, H)
        # The own images are the mosaics' tiles (views; the tiles do not overlap).
        own_s = mos_s[ty : ty + bh, tx : tx + bw]
        own_r = mos_r[ty : ty + bh, tx : tx + bw]
        if fx1 > fx0 and fy1 > fy0:
            own_s[fy0 - oy : fy1 - oy, fx0 - ox : fx1 - ox] = smooth[fy0:fy1, fx0:fx1]
            own_r[fy0 - oy : fy1 - oy, fx0 - ox : fx1 - ox] = signal[fy0:fy1, fx0:fx1]
        for j in np.flatnonzero(meet[k]).tolist():
            q = pl[j]
            qx, qy, qw, qh = q.tpl.box
            dx, dy = qx + shifts[j][0] - ox, qy + shifts[j][1] - oy
            if dx >= bw or dy >= bh or dx + qw <= 0 or dy + qh <= 0:
                continue
            if j not in placed:
                placed[j] = _placed_tile(q)
            bx, by, t_s, t_r = placed[j]
            # The tile's part inside the own image (origin ``bx - ox, by - oy`` there).
            u0, v0 = bx - ox, by - oy
            a0, b0 = max(u0, 0), max(v0, 0)
            a1, b1 = min(u0 + t_s.shape[1], bw), min(v0 + t_s.shape[0], bh)
            if a1 <= a0 or b1 <= b0:
                continue
            own_s[b0:b1, a0:a1] -= t_s[b0 - v0 : b1 - v0, a0 - u0 : a1 - u0]
            own_r[b0:b1, a0:a1] -= t_r[b0 - v0 : b1 - v0, a0 - u0 : a1 - u0]
        back[k] = (ox - tx, oy - ty)
        lines.append(p.tpl.points + p.shift - back[k])
    return mos_s, mos_r, lines, back


def _placed_tile(q: Placement) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Placement ``q``'s smoothed and raw templates times its amplitude at its sub-pixel
    place: the frame's integer origin ``bx, by`` of the ``(h + 1, w + 1)`` tiles."""
    qx, qy, qw, qh = q.tpl.box
    X, Y = qx + q.shift[0], qy + q.shift[1]
    bx, by = int(np.floor(X)), int(np.floor(Y))
    fx, fy = X - bx, Y - by
    t_s = q.amp * warp(q.tpl.smooth, fx, fy, qw + 1, qh + 1)
    t_r = q.amp * warp(q.tpl.raw, fx, fy, qw + 1, qh + 1)
    return bx, by, t_s, t_r
