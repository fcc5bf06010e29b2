"""Joint refinement of template placements that overlap
(:mod:`blurtrack.detect.separation.separate`).

The matching pursuit places one template at a time, each at the best match of what the
earlier ones left. Where two streaks run along each other (a dot's streak overlapping the next
one's for part of its length, collinear or offset by a pixel or two) the correlation of one
template with the pair is *flat* along the shared part: for straight streaks of length ``L``
whose union has length ``L_c``, every position in ``[0, L_c - L]`` covers the doubled part
and correlates alike, so the first placement lands anywhere there and the measured ends land
several pixels off. The least-squares fit of both placements together is unique (the union's
two ends anchor them), and coordinate descent finds it: each placement in turn is moved to the
best match of the light minus the *other* placements' templates (unclamped, so light that an
earlier placement took twice shows as a deficit), its amplitude re-solved, for a few rounds.
In one dimension one step from any start in ``[0, L_c - L]`` lands the second placement on
an end, and the next puts the first on the other.
"""

from __future__ import annotations

import cv2
import numpy as np

from blurtrack.detect.paramsections import SeparationParams
from blurtrack.detect.separation.templates import (
    InsideNorms,
    Placement,
    inside_norm2,
    warp,
)

#: Coordinate-descent rounds over the overlapping placements; a budget: the rounds stop early
#: where no placement moved.
ROUNDS = 3


def _tile(p: Placement) -> tuple[int, int, np.ndarray]:
    """``amp * template`` at its sub-pixel place: the integer origin and the tile."""
    x, y, w, h = p.tpl.box
    ox, oy = x + p.shift[0], y + p.shift[1]
    bx, by = int(np.floor(ox)), int(np.floor(oy))
    return bx, by, p.amp * warp(p.tpl.smooth, ox - bx, oy - by, w + 1, h + 1)


def _paint(model: np.ndarray, tile: tuple[int, int, np.ndarray], sign: float) -> None:
    """Add ``sign`` x a :func:`_tile` into ``model`` (in place)."""
    H, W = model.shape
    bx, by, t = tile
    h, w = t.shape
    x0, y0, x1, y1 = max(bx, 0), max(by, 0), min(bx + w, W), min(by + h, H)
    if x1 > x0 and y1 > y0:
        model[y0:y1, x0:x1] += sign * t[y0 - by : y1 - by, x0 - bx : x1 - bx]


def model_image(like: np.ndarray, pl: list[Placement]) -> np.ndarray:
    """``sum amp * template`` of the placements ``pl`` at their sub-pixel places, on an image
    of ``like``'s shape and type (as :func:`refit` paints them)."""
    out = np.zeros_like(like)
    for p in pl:
        _paint(out, _tile(p), 1.0)
    return out


def _neighbours(pl: list[Placement]) -> list[list[int]]:
    """Per placement, the others whose support meets its support or halo (the light they
    model is shared)."""
    org = np.rint([[p.tpl.box[0] + p.shift[0], p.tpl.box[1] + p.shift[1]] for p in pl])
    org = org.astype(np.int64)
    end = org + np.array([[p.tpl.box[2], p.tpl.box[3]] for p in pl], np.int64)
    meet = np.all(np.maximum(org[:, None], org[None]) < np.minimum(end[:, None], end[None]), axis=2)
    out: list[list[int]] = [[] for _ in pl]
    for i, j in zip(*np.nonzero(np.triu(meet, 1)), strict=True):
        lo, hi = np.maximum(org[i], org[j]), np.minimum(end[i], end[j])
        oi, oj = lo - org[i], lo - org[j]
        ext = hi - lo
        ai = pl[i].tpl.support[oi[1] : oi[1] + ext[1], oi[0] : oi[0] + ext[0]]
        aj = pl[j].tpl.support[oj[1] : oj[1] + ext[1], oj[0] : oj[0] + ext[0]]
        hi_ = pl[i].tpl.halo[oi[1] : oi[1] + ext[1], oi[0] : oi[0] + ext[0]]
        hj = pl[j].tpl.halo[oj[1] : oj[1] + ext[1], oj[0] : oj[0] + ext[0]]
        if np.any(ai * (aj + hj)) or np.any(aj * hi_):
            out[int(i)].append(int(j))
            out[int(j)].append(int(i))
    return out


_U, _V = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0])
#: Least-squares fit of ``c0 + c1 u + c2 v + c3 u^2 + c4 u v + c5 v^2`` to a 3 x 3 patch.
_QUAD = np.linalg.pinv(
    np.column_stack(
        [np.ones(9), _U.ravel(), _V.ravel(), _U.ravel() ** 2, (_U * _V).ravel(), _V.ravel() ** 2]
    )
)


def _peak(num: np.ndarray, iy: int, ix: int) -> tuple[float, float]:
    """Sub-pixel offset of the integer maximum ``num[iy, ix]``: the stationary point of the
    2-D quadratic fitted to its 3 x 3 neighbourhood (a streak's correlation peak is a ridge
    along the streak, which separate parabolas in x and y misplace where it runs
    diagonally), within one pixel; (0, 0) at the border or where the fit has no maximum."""
    h, w = num.shape
    if not (0 < iy < h - 1 and 0 < ix < w - 1):
        return 0.0, 0.0
    c = (_QUAD @ num[iy - 1 : iy + 2, ix - 1 : ix + 2].ravel().astype(np.float64)).tolist()
    # The Hessian [[a, b], [b, d]] and its stationary point by Cramer's rule (2 x 2).
    a, b, d = 2.0 * c[3], c[4], 2.0 * c[5]
    det = a * d - b * b
    if not (a < 0 and det > 0):
        return 0.0, 0.0
    fx = (b * c[2] - d * c[1]) / det
    fy = (b * c[1] - a * c[2]) / det
    return min(max(fx, -1.0), 1.0), min(max(fy, -1.0), 1.0)


def refit(
    light: np.ndarray,
    pl: list[Placement],
    sp: SeparationParams,
    frame: tuple[int, int, int, int] | None = None,
    norms: InsideNorms | None = None,
) -> tuple[list[Placement], np.ndarray | None]:
    """Coordinate descent of the placements whose templates meet another's on ``light``
    (the candidates' light, float32, frame coordinates; ``frame``: for a ``light`` padded
    with zeros beyond the frame, the frame's pixels in it, and a placement reaching past the border
    is scaled by its template's part inside, see
    :func:`blurtrack.detect.separation.templates.inside_norm2`; ``norms``: those norms
    remembered over calls, its ``frame`` being ``frame``; ``sp``: the step's reach, the
    amplitude it keeps, ``inside_min``).

    Returns the placements (moved and re-scaled where that fits better; the others as they
    were) and the model image ``sum amp * template`` of all of them (None when no
    placement meets another: nothing moved).
    """
    if len(pl) < 2:
        return pl, None
    nb = _neighbours(pl)
    active = {k for k in range(len(pl)) if nb[k]}
    if not active:
        return pl, None
    H, W = light.shape
    out = list(pl)
    model = np.zeros_like(light)
    tiles = [_tile(p) for p in out]
    for t in tiles:
        _paint(model, t, 1.0)
    for _ in range(ROUNDS):
        moved: set[int] = set()
        for k in sorted(active):
            p = out[k]
            x, y, w, h = p.tpl.box
            r = int(np.clip(sp.reach_fraction * max(w, h), sp.reach_min_px, sp.reach_max_px))
            bx, by = int(np.rint(x + p.shift[0])), int(np.rint(y + p.shift[1]))
            x0, y0 = max(bx - r, 0), max(by - r, 0)
            x1, y1 = min(bx + w + r, W), min(by + h + r, H)
            if x1 - x0 < w + 2 or y1 - y0 < h + 2:
                continue
            _paint(model, tiles[k], -1.0)
            rest = light[y0:y1, x0:x1] - model[y0:y1, x0:x1]
            num = cv2.matchTemplate(rest, p.tpl.smooth, cv2.TM_CCORR)
            box = (x0, y0, x1, y1)
            n2 = (
                inside_norm2(frame, box, p.tpl.smooth)
                if norms is None
                else norms(box, p.tpl.smooth)
            )
            pick = num if n2 is None else np.where(n2 >= sp.inside_min * p.tpl.norm2, num, -np.inf)
            iy, ix = (int(v) for v in np.unravel_index(int(np.argmax(pick)), pick.shape))
            amp = float(num[iy, ix]) / (p.tpl.norm2 if n2 is None else float(n2[iy, ix]))
            if amp >= sp.amp_keep:
                fx, fy = _peak(num, iy, ix)
                shift = np.array([x0 + ix + fx - x, y0 + iy + fy - y])
                if np.any(np.abs(shift - p.shift) > 0.05):
                    moved.add(k)
                out[k] = Placement(p.tpl, shift, amp, p.comp)
                tiles[k] = _tile(out[k])
            _paint(model, tiles[k], 1.0)
        # Next round: the placements that moved and those sharing light with them.
        active = moved.union(*(nb[k] for k in moved))
        if not active:
            break
    return out, model
