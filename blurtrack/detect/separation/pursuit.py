"""Matching pursuit of one template over a component's light (the separation of touching
streaks, :mod:`blurtrack.detect.separation.separate`, and the template pass,
:mod:`blurtrack.detect.gyro.gyropass`).

The template ``T`` is correlated with the residual image ``X`` (OpenCV ``matchTemplate``); a
placement's score is the normalised correlation over the template's support, its amplitude
``<T, X> / |T|^2``; the best placements above ``separation.score_min`` and ``amp_min``
(:class:`~blurtrack.detect.paramsections.SeparationParams`) are taken, ``a T`` subtracted,
for up to :data:`MAX_ROUNDS` rounds. Positions in pixels of the (possibly padded) images,
refined to sub-pixel by a parabola through the score's peak.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.detect.lines.segment import Components
from blurtrack.detect.paramsections import SeparationParams
from blurtrack.detect.separation.templates import (
    HALO_PX,
    InsideNorms,
    Placement,
    Template,
    inside_norm2,
)

#: Rounds of the pursuit (each takes every good placement that keeps ``separation.suppress``
#: x the template's size from a better one, then subtracts them all); a budget: the rounds
#: stop early where nothing is placed or too little light is left (``separation.left_min``).
MAX_ROUNDS = 3
#: Matched-filter peaks tried per round, and how far (px) a refused one suppresses its
#: neighbours.
MAX_TRIES = 16
FAIL_SUPPRESS_PX = 2


def _subpixel(score: np.ndarray, iy: int, ix: int) -> tuple[float, float]:
    """Parabolic refinement of an integer maximum of ``score``."""

    def para(a: float, b: float, c: float) -> float:
        den = a - 2.0 * b + c
        return float(min(max(0.5 * (a - c) / den, -0.5), 0.5)) if den < 0 else 0.0

    h, w = score.shape
    fx = para(score[iy, ix - 1], score[iy, ix], score[iy, ix + 1]) if 0 < ix < w - 1 else 0.0
    fy = para(score[iy - 1, ix], score[iy, ix], score[iy + 1, ix]) if 0 < iy < h - 1 else 0.0
    return fx, fy


@dataclass(frozen=True)
class PursuitFrame:
    """What the pursuits of one frame share: its components ``comps`` in the residual's
    coordinates and the component index of each of their labels ``comp_of_label`` (``(max
    label + 1,)``, -1: none); for a residual padded with zeros beyond the frame, the frame's
    pixels in it ``inside`` (``(x0, y0, x1, y1)``, None: not padded;
    :func:`blurtrack.detect.separation.templates.inside_norm2`) and the norms remembered over
    the frame's pursuits and refits ``norms`` (None: computed per call; its ``frame`` is
    ``inside``)."""

    comps: Components
    comp_of_label: np.ndarray
    inside: tuple[int, int, int, int] | None = None
    norms: InsideNorms | None = None


def pursue(
    residual: np.ndarray,
    where: PursuitFrame,
    c: int,
    tpl: Template,
    sp: SeparationParams,
    halo_max: float,
    limit: int | None = None,
) -> list[Placement]:
    """Matching pursuit of ``tpl`` over candidate ``c``'s neighbourhood of ``residual`` (which
    it updates in place; component ``c`` of ``where.comps``). Each placement belongs to the
    component that holds most of the light it explains (``where.comp_of_label``). ``sp``: the
    thresholds; ``halo_max``: ``sp.halo_max`` or ``sp.halo_max_whole``.

    Where ``where.inside`` is set (a ``residual`` padded with zeros beyond the frame), a
    placement reaching past the border is scored and scaled by its template's part inside the
    frame (a streak leaving the frame), and needs at least ``sp.inside_min`` of its template
    inside.
    ``limit``: at most this many placements (at least 1; the best first; None: as many as
    fit)."""
    if limit is not None and limit < 1:
        raise ValueError(f"pursue: limit must be at least 1, got {limit}")
    comps, comp_of_label, frame, norms = where.comps, where.comp_of_label, where.inside, where.norms
    H, W = residual.shape
    x, y, w, h = (int(v) for v in comps.boxes[c])
    tx, ty, tw, th = tpl.box
    # Placements whose centre lies in the candidate's box (+ a margin) only.
    m = HALO_PX + 1
    x0, y0 = max(x - m - tw // 2, 0), max(y - m - th // 2, 0)
    x1, y1 = min(x + w + m + tw - tw // 2, W), min(y + h + m + th - th // 2, H)
    if x1 - x0 < tw or y1 - y0 < th:
        return []
    region = residual[y0:y1, x0:x1]  # a view: subtractions update the residual
    # The matched filter at a window is at most the product of the window's and the
    # template's norms (Cauchy-Schwarz; past the frame the residual is zero, so the
    # template's part inside it), so no placement reaches ``amp_min`` where the whole
    # region holds less light than the template at that amplitude: no filter to run (a
    # thousandth below the bound: the filter sums in float32).
    floor = sp.amp_min**2 * tpl.norm2 * (1.0 if frame is None else sp.inside_min)
    if cv2.norm(region, cv2.NORM_L2SQR) < 0.999 * floor:
        return []
    out: list[Placement] = []
    norm = float(np.sqrt(tpl.norm2))
    sx, sy = max(int(sp.suppress * tw), 1), max(int(sp.suppress * th), 1)
    # The same region every round.
    box = (x0, y0, x1, y1)
    n2 = inside_norm2(frame, box, tpl.smooth) if norms is None else norms(box, tpl.smooth)
    for _ in range(MAX_ROUNDS):
        # The matched filter's peaks are the candidates; the normalised score and the halo
        # are evaluated at those few positions only.
        num = cv2.matchTemplate(region, tpl.smooth, cv2.TM_CCORR)
        if n2 is None:
            open_ = np.where(num >= sp.amp_min * tpl.norm2, num, 0.0)
        else:
            open_ = np.where((num >= sp.amp_min * n2) & (n2 >= sp.inside_min * tpl.norm2), num, 0.0)
        picked: list[tuple[int, int, float]] = []
        for _try in range(MAX_TRIES):
            jy, jx = np.unravel_index(int(np.argmax(open_)), open_.shape)
            iy, ix = int(jy), int(jx)
            if open_[iy, ix] <= 0.0:
                break
            win = region[iy : iy + th, ix : ix + tw]
            w2 = win * win
            den = float(np.sum(w2 * tpl.support))
            halo = float(np.sum(w2 * tpl.halo))
            t2 = tpl.norm2 if n2 is None else float(n2[iy, ix])
            t1 = norm if n2 is None else float(np.sqrt(t2))
            score = float(num[iy, ix]) / (np.sqrt(max(den, 0.0)) * t1 + 1e-12)
            # A streak's template lies in the dark: no blob or wider streak fits it.
            if score >= sp.score_min and halo <= halo_max * den:
                picked.append((iy, ix, float(num[iy, ix]) / t2))
                if limit is not None and len(out) + len(picked) >= limit:
                    break
                ry, rx = sy, sx
            else:
                ry, rx = FAIL_SUPPRESS_PX, FAIL_SUPPRESS_PX
            open_[max(iy - ry, 0) : iy + ry + 1, max(ix - rx, 0) : ix + rx + 1] = 0.0
        if not picked:
            break
        for iy, ix, a in picked:
            fx, fy = _subpixel(num, iy, ix)
            shift = np.array([x0 + ix + fx - tx, y0 + iy + fy - ty])
            win = region[iy : iy + th, ix : ix + tw]
            lab = comps.labels[y0 + iy : y0 + iy + th, x0 + ix : x0 + ix + tw]
            owner = comp_of_label[lab]
            light = np.bincount(owner[owner >= 0], (win * tpl.smooth)[owner >= 0])
            out.append(Placement(tpl, shift, a, int(np.argmax(light)) if light.size else c))
            win -= a * tpl.smooth
            np.maximum(win, 0.0, out=win)
        if limit is not None and len(out) >= limit:
            break
        # Another round only if the candidate's box still holds a good part of a template.
        left = residual[y : y + h, x : x + w]
        if float(np.sum(left * left)) < sp.left_min * sp.amp_min**2 * tpl.norm2:
            break
    return out
