"""Anchored placement of the modal template on fragments (whole-component references only).

A faint light on a string (night2 of the real photographs) is above the threshold only where it is
brightest, its hook or its foot: the first pass and the separation measure that part, a *fragment*
far shorter than the frame's consensus vector. The rest of the light is in the image, below the
threshold. With whole-component references (:mod:`blurtrack.detect.separation.modal`) every light
drew the reference's curve, so the nearest reference's template, mapped onto the local consensus
(:func:`blurtrack.detect.separation.templates.similar`), is matched to the smoothed image around
each fragment at any amplitude down to ``separation.anchor_amp_min`` (relative to the reference),
with two conditions that keep it on the fragment's own light: its support covers
``separation.anchor_cover_min`` of the fragment's centre line (the *anchor*), and its normalised
correlation over the support is at least ``separation.anchor_score_min``. The light of every other
component is removed from the image first (neighbouring lights are not matched). The placed centre
line is then measured on that image (:func:`blurtrack.detect.lines.measure.measure_lines`) and
replaces the fragment only when the measurement agrees with the local consensus within the shape
tolerance (:func:`blurtrack.detect.separation.consensus.shape_tolerance`). Pixels, frame
coordinates.
"""

from __future__ import annotations

import cv2
import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.lines.measure import LineSet, Measured, combine, measure_lines
from blurtrack.detect.paramsections import SeparationParams
from blurtrack.detect.separation.consensus import Consensus, nearest_sign, shape_tolerance
from blurtrack.detect.separation.templates import Template, similar, template


def _place(
    x: np.ndarray, anchor: np.ndarray, tpl: Template, sp: SeparationParams
) -> tuple[int, int, float, float] | None:
    """Best position ``(iy, ix)`` of ``tpl`` in ``x`` (its amplitude and score) among those
    whose support covers ``sp.anchor_cover_min`` of the ``anchor`` mask; None if none
    passes."""
    th, tw = tpl.smooth.shape
    if x.shape[0] < th or x.shape[1] < tw:
        return None
    num = cv2.matchTemplate(x, tpl.smooth, cv2.TM_CCORR)
    den = cv2.matchTemplate(x * x, tpl.support, cv2.TM_CCORR)
    cover = cv2.matchTemplate(anchor, tpl.support, cv2.TM_CCORR) / max(float(anchor.sum()), 1.0)
    score = num / (np.sqrt(np.maximum(den, 0.0)) * np.sqrt(tpl.norm2) + 1e-12)
    amp = num / tpl.norm2
    ok = (cover >= sp.anchor_cover_min) & (amp >= sp.anchor_amp_min)
    ok &= score >= sp.anchor_score_min
    if not ok.any():
        return None
    best = np.where(ok, score, -1.0)
    iy, ix = (int(t) for t in np.unravel_index(int(np.argmax(best)), best.shape))
    return iy, ix, float(amp[iy, ix]), float(score[iy, ix])


def anchored(
    ctx: FrameContext, m: Measured, refs: Measured, good: np.ndarray, field: Consensus
) -> tuple[Measured, int]:
    """The streaks ``m`` with their fragments replaced by anchored placements (see the module
    text), and how many were replaced. Streaks near the border are never fragments;
    ``refs``/``good``: the whole-component references and those that agree with ``field``."""
    smooth, signal, comps = ctx.smooth, ctx.signal, ctx.comps
    sp = ctx.params.separation
    clipped = ctx.clipped(m.end_a, m.end_b)
    c = field.at(m.time_mid)
    L = np.hypot(*c.T)
    v = m.end_b - m.end_a
    dev = nearest_sign(v, c)[1]
    tol = shape_tolerance(c, ctx.params.quality)
    frag = ~clipped & (sp.fragment_min_px <= L) & (np.hypot(*v.T) < sp.fragment_fraction * L)
    frag &= dev > tol
    ref_idx = np.flatnonzero(good)
    if not frag.any() or ref_idx.size == 0:
        return m, 0
    H, W = ctx.shape
    bases: dict[int, Template] = {}
    found: list[tuple[int, Measured]] = []
    for i in np.flatnonzero(frag).tolist():
        d2 = np.sum((refs.time_mid[ref_idx] - m.time_mid[i]) ** 2, axis=1)
        k = int(ref_idx[int(np.argmin(d2))])
        vk = complex(*field.at(refs.time_mid[k : k + 1])[0])
        zt = complex(*c[i])
        z = zt / vk if (zt / vk).real > 0 else -zt / vk
        if not 0.7 < abs(z) < 1.4:
            continue
        if k not in bases:
            bases[k] = template(smooth, signal, comps, int(refs.own[k]), refs.points[k])
        tpl = similar(bases[k], z, refs.time_mid[k]) if abs(z - 1) > 0.02 else bases[k]
        th, tw = tpl.smooth.shape
        pts = m.points[i]
        x0 = max(int(np.floor(pts[:, 0].min())) - tw, 0)
        y0 = max(int(np.floor(pts[:, 1].min())) - th, 0)
        x1 = min(int(np.ceil(pts[:, 0].max())) + tw + 1, W)
        y1 = min(int(np.ceil(pts[:, 1].max())) + th + 1, H)
        lab = comps.labels[y0:y1, x0:x1]
        own = (lab == 0) | (lab == comps.ids[int(m.own[i])])
        xs = np.where(own, smooth[y0:y1, x0:x1], 0.0).astype(np.float32)
        xr = np.where(own, signal[y0:y1, x0:x1], 0.0).astype(np.float32)
        np.maximum(xs, 0.0, out=xs)
        anchor = np.zeros(xs.shape, np.float32)
        q = np.rint(pts - [x0, y0]).astype(int)
        inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < xs.shape[1]) & (q[:, 1] < xs.shape[0])
        anchor[q[inside, 1], q[inside, 0]] = 1.0
        hit = _place(xs, anchor, tpl, sp)
        if hit is None:
            continue
        iy, ix, _, _ = hit
        line = tpl.points - [tpl.box[0], tpl.box[1]] + [ix, iy]
        ls = LineSet([line], [int(m.own[i])], [False], [False])
        got = measure_lines(ctx.on(xs, xr), ls, m.sigma_c, False, m.sigma_raw)
        if len(got) != 1:
            continue
        w = got.end_b[0] - got.end_a[0]
        d = min(np.hypot(*(w - c[i])), np.hypot(*(w + c[i])))
        if d > tol[i]:
            continue
        off = np.array([x0, y0], np.float64)
        got.end_a, got.end_b, got.time_mid = got.end_a + off, got.end_b + off, got.time_mid + off
        got.points = [got.points[0] + off]
        found.append((i, got))
    if not found:
        return m, 0
    # Fragments of one light give one placement (the first by streak order stands), and a
    # placement on a streak that is already whole is that streak: the fragment stays.
    keep = np.ones(len(m), bool)
    same = sp.same_light_fraction
    whole_mid = m.time_mid[~frag]
    mids: list[np.ndarray] = []
    out: Measured | None = None
    for i, got in found:
        mid = got.time_mid[0]
        if whole_mid.size and np.min(np.hypot(*(whole_mid - mid).T)) < same * L[i]:
            continue
        keep[i] = False
        if any(np.hypot(*(mid - o)) < same * L[i] for o in mids):
            continue
        mids.append(mid)
        out = got if out is None else combine(out, np.ones(len(out), bool), got)
    return combine(m, keep, out), len(mids)
