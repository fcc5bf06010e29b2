"""The gyro pass's shape search (:mod:`blurtrack.detect.gyro.gyropass`): the rotation and scale of
a predicted curve whose template explains a component's light best.

Calibration is nominal, so the predicted curve is off by a px or two: it is rotated and
scaled about its centroid (its light's), a coordinate search (:data:`ROTATIONS_RAD` at the
nominal scale, :data:`SCALES` at the rotation picked, :data:`FINE_ROTATIONS_RAD` about it)
ranked by the correlation normalised over the template's support *and halo*. The nominal
shape is matched over the whole component box; the variants, whose best placements lie a px
or two from the nominal's, only within :data:`SHIFT_WINDOW_PX` of it (hard seeds 1-3, 10
frames: the same recall, precision and endpoint error as the whole box, the variants' match
a third of the work).

Placements over no light are not ranked: there both correlations are the DFT's rounding
(~1e-7 of their largest, either sign) and their ratio is noise, up to 1e4 where a correlation
is at most 1 (before :data:`DEN_FLOOR`, 44 % of the trials on a hard session picked such a
placement, and the search with them a shape at random).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from blurtrack.detect.gyro.gyrocurve import similar_curve
from blurtrack.detect.lines.segment import Components
from blurtrack.detect.separation.templates import Template, inside_norm2

#: Shape search (calibration error): rotations (rad) and scales of the predicted curve.
ROTATIONS_RAD = (-0.06, -0.03, 0.0, 0.03, 0.06)
SCALES = (0.92, 0.94, 0.96, 0.98, 1.0, 1.02, 1.04, 1.06, 1.08)
FINE_ROTATIONS_RAD = (-0.015, 0.015)
#: Placements whose support and halo hold less than this fraction of the largest such light
#: (in squares) of the box are not ranked (their correlations are rounding).
DEN_FLOOR = 1e-5
#: The shape variants are matched within this many px of the nominal shape's best placement.
SHIFT_WINDOW_PX = 3


def best_shape(
    light: np.ndarray,
    comps: Components,
    c: int,
    pts: np.ndarray,
    make: Any,
    inside_min: float,
    frame: tuple[int, int, int, int] | None = None,
) -> tuple[Template | None, float]:
    """The variant of curve ``pts`` (rotated, scaled) whose template explains the light in
    component ``c``'s box best, and its support-normalised correlation there (only where the
    calibration is nominal: a calibration corrected for the session,
    :mod:`blurtrack.detect.gyro.sessioncalib`, places the curve as predicted, without a trial).

    The variants are ranked by the correlation normalised over the support *and the halo*:
    the support-normalised one alone (the pursuit's) is as high for a template too small,
    lying inside the streak, as for the right one; light past the template's ends, in its
    halo, tells them apart.

    ``frame``: for a ``light`` padded with zeros beyond the frame, the frame's pixels in it
    ``(x0, y0, x1, y1)``; a
    placement reaching past the border is normalised by its template's part inside the frame
    (at least ``inside_min`` of it: ``separation.inside_min``), so a streak leaving
    the frame is matched by its predicted curve cut at the border.
    """
    x, y, w, h = (int(v) for v in comps.boxes[c])
    tried: dict[tuple[float, float], _Trial] = {}
    near: tuple[int, int, float] | None = None

    def trial(r: float, sc: float) -> _Trial:
        key = (round(r, 9), round(sc, 9))
        if key not in tried:  # the search comes back to its pick: the same trial
            tpl = make(similar_curve(pts, sc * np.exp(1j * r)))
            tried[key] = _trial(light, (x, y, w, h), tpl, inside_min, near, frame)
        return tried[key]

    # The nominal shape over the whole box; the variants (a px or two from it) about its
    # best placement only (SHIFT_WINDOW_PX).
    first = trial(0.0, 1.0)
    if first[0] is None:
        return None, -1.0
    near = (first[3][0], first[3][1], first[4])
    # Coordinate search: the rotation at the nominal scale, the scale at that rotation, then
    # the rotation once more on a finer grid.
    best: _Trial = first
    rot, scale = 0.0, 1.0
    for grid, which in ((ROTATIONS_RAD, "r"), (SCALES, "s"), (FINE_ROTATIONS_RAD, "f")):
        pick = (rot, scale)
        for v in grid:
            r, sc = (v, scale) if which == "r" else (rot, v) if which == "s" else (rot + v, scale)
            got = trial(r, sc)
            if got[2] > best[2]:
                best, pick = got, (r, sc)
        rot, scale = pick
    return best[0], best[1]


#: One trial of the shape search: the template, its support- and halo-normalised
#: correlations at its best placement, that placement (the curve's integer shift) and the
#: largest support-and-halo light of the placements searched.
_Trial = tuple[Template | None, float, float, tuple[int, int], float]


def _trial(
    light: np.ndarray,
    box: tuple[int, int, int, int],
    tpl: Template,
    inside_min: float,
    near: tuple[int, int, float] | None = None,
    frame: tuple[int, int, int, int] | None = None,
) -> _Trial:
    """Template ``tpl`` matched over the component box ``box`` of ``light`` (every placement
    whose top-left lies within half the template of the box, 2 px more; with ``near = (sx,
    sy, top)`` only those within :data:`SHIFT_WINDOW_PX` of the curve's shift ``sx, sy``,
    ``top`` the largest light of the whole box's): see :data:`_Trial` (:func:`best_shape`).
    The template's zero border (past its halo) is cropped off and the region with it: the
    same placements, the same sums, less to correlate."""
    H, W = light.shape
    x, y, w, h = box
    tx, ty, tw, th = tpl.box
    none: _Trial = (None, -1.0, -1.0, (0, 0), 0.0)
    # Top-left corners searched, frame px, inclusive.
    px0, py0 = max(x - tw // 2 - 2, 0), max(y - th // 2 - 2, 0)
    px1, py1 = min(x + w + tw // 2 + 2, W) - tw, min(y + h + th // 2 + 2, H) - th
    if near is not None:
        R = SHIFT_WINDOW_PX
        px0, px1 = max(px0, tx + near[0] - R), min(px1, tx + near[0] + R)
        py0, py1 = max(py0, ty + near[1] - R), min(py1, ty + near[1] + R)
    # A curve predicted off the canvas splats no light: a template of norm 0 explains nothing
    # (its correlations would be 0 / 0).
    if px1 < px0 or py1 < py0 or not tpl.norm2 > 0.0:
        return none
    mask = tpl.support + tpl.halo
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    a, b, cl, cr = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    region = light[py0 + a : py1 + b, px0 + cl : px1 + cr]
    sm, mk, sup = tpl.smooth[a:b, cl:cr], mask[a:b, cl:cr], tpl.support[a:b, cl:cr]
    num = cv2.matchTemplate(region, sm, cv2.TM_CCORR)
    sq = region * region
    den_h = cv2.matchTemplate(sq, mk, cv2.TM_CCORR)
    top = float(den_h.max()) if near is None else near[2]
    if not top > 0.0:
        return none
    # Placements over (next to) no light: both sums are the DFT's rounding there (~1e-7 of
    # their largest, of either sign), and so is their ratio: no rank.
    lit = den_h > DEN_FLOOR * top
    # Placements past the frame's border: the template's part inside the frame.
    n2 = inside_norm2(frame, (px0 + cl, py0 + a, px1 + cr, py1 + b), sm)
    if n2 is None:
        norm: Any = np.sqrt(tpl.norm2)
    else:
        lit &= n2 >= inside_min * tpl.norm2
        norm = np.sqrt(np.maximum(n2, 1e-30))
    if not lit.any():
        return none
    rank = np.where(lit, num / (np.sqrt(np.where(lit, den_h, 1.0)) * norm), -1.0)
    ky, kx = (int(v) for v in np.unravel_index(int(np.argmax(rank)), rank.shape))
    shift = (px0 + kx - tx, py0 + ky - ty)
    den_s = float(np.sum(sq[ky : ky + b - a, kx : kx + cr - cl] * sup))
    if not den_s > DEN_FLOOR * float(den_h[ky, kx]):
        return tpl, -1.0, float(rank[ky, kx]), shift, top
    score = float(num[ky, kx]) / (np.sqrt(den_s) * float(np.broadcast_to(norm, num.shape)[ky, kx]))
    return tpl, score, float(rank[ky, kx]), shift, top
