"""Separation of touching and overlapping streaks with the frame's own streak as a template.

Within one frame every dot draws nearly the same curve: the camera's rotation moves every dot
alike, up to perspective and the rolling shutter, which vary slowly over the frame. So a clean,
isolated streak is a matched template for its neighbours (shape *and* brightness profile).

1. **Consensus** (:func:`blurtrack.detect.separation.consensus.consensus_field`): the robust affine
   field of the start-to-end vectors of the first pass's unflagged streaks.
2. **Candidates**: components whose lines are flagged (crossing, looped, merged), deviate from
   the consensus by more than the quality tolerance (chains of several streaks, fragments,
   hooks), or that gave no measurable line at all.
3. **Matching pursuit** per candidate, with the nearest *reference* (an unflagged streak whose
   vector agrees with the consensus; its component's pixels of the smoothed image are the
   template ``T``): the normalised correlation over the template's support,
   ``<T, X> / (|T| |X|_support)``, is 1 where ``X`` holds a scaled copy of ``T`` whatever lies
   outside, and about ``sqrt(f)`` where only a fraction ``f`` of a collinear neighbour overlaps;
   the best placement above ``separation.score_min`` with an amplitude ``<T, X> / |T|^2``
   above ``separation.amp_min`` is accepted and
   ``a T`` subtracted from the candidates' residual image, until none is left
   (:func:`blurtrack.detect.separation.pursuit.pursue`). Fragments of one streak (a dim middle) are
   joined: one placement explains both. Placements that share light are then fitted together
   (:mod:`blurtrack.detect.separation.refit`). Components that the accepted placements explain (most
   of their light) are replaced.
4. **Measurement**: each placement gets its own image, the smoothed (and raw) frame around it
   minus the templates of the *other* placements that overlap it, all tiled into one mosaic;
   the placed centre lines (the reference's, shifted) are measured there by
   :func:`blurtrack.detect.lines.measure.measure_lines` exactly like the first pass's, and moved
   back (:mod:`blurtrack.detect.separation.mosaic`). Placements whose templates overlap by
   more than ``separation.overlap_fraction`` are
   ``crossing``.

Thresholds: :class:`~blurtrack.detect.paramsections.SeparationParams` (``separation`` of
:class:`~blurtrack.detect.params.DetectParams`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.lines.measure import LineSet, Measured, combine, measure_lines
from blurtrack.detect.separation.consensus import (
    Consensus,
    consensus_field,
    shape_tolerance,
)
from blurtrack.detect.separation.modal import component_references
from blurtrack.detect.separation.mosaic import overlapping_placements, placement_mosaic
from blurtrack.detect.separation.pursuit import PursuitFrame, pursue
from blurtrack.detect.separation.refit import refit
from blurtrack.detect.separation.templates import (
    Placement,
    Template,
    similar,
    template,
)


@dataclass(frozen=True)
class Separation:
    """What :func:`separate` found (see there)."""

    streaks: Measured | None
    replaced: np.ndarray | None
    field: Consensus | None
    #: The whole-component references (:mod:`blurtrack.detect.separation.modal`) and those that
    #: agree with the field, where the frame took them (else None).
    refs: Measured | None = None
    good: np.ndarray | None = None


def separate(ctx: FrameContext, first: Measured, folded: np.ndarray) -> Separation:
    """Template separation of the first pass's doubtful components (see the module text).

    Args:
        ctx: the frame.
        first: the first pass's streaks.
        folded: ``(C,)`` bool, the components the skeleton tracer took.
    Returns:
        The separated streaks (frame coordinates; None when nothing was separated), the
        ``(C,)`` bool mask of the components they replace, and the frame's consensus field
        (None without enough voters).
    """
    lines = _first_lines(ctx, first)
    # 1. Consensus, and the references that agree with it.
    field = consensus_field(lines.v, first.time_mid, lines.voters, ctx.params.quality)
    refs = _references(ctx, first, lines, field)
    if refs is None:
        return Separation(None, None, field)
    # 2. Candidates.
    cands = _candidates(ctx, first, folded, lines, refs)
    if cands is None:
        return _finish(ctx, first, lines, refs, None, None)
    # 3. Matching pursuit, joint fit, the components the placements explain.
    pur = _pursue_candidates(ctx, refs, cands)
    if not pur.placements:
        return _finish(ctx, first, lines, refs, None, None)
    replaced, placements = _replaced(ctx, first, lines, refs, cands, pur)
    if not placements:
        return _finish(ctx, first, lines, refs, None, None)
    # 4. Measurement on each placement's own image.
    m = _measure(ctx, first, placements)
    return _finish(ctx, first, lines, refs, m, replaced)


@dataclass(frozen=True)
class _FirstLines:
    """What the stages use of the first pass's ``N`` streaks (``C`` components)."""

    #: ``(N,)`` bool: the streak ends at the frame's border (:meth:`FrameContext.clipped`).
    clipped: np.ndarray
    #: ``(N,)`` bool: the streak is wider than one (:meth:`FrameContext.merged`).
    merged: np.ndarray
    #: ``(N, 2)`` px: each streak's start-to-end vector.
    v: np.ndarray
    #: ``(C,)`` the number of streaks of each component.
    n_lines: np.ndarray
    #: ``(N,)`` bool: the streaks that vote for the consensus (alone in their component, not
    #: flagged).
    voters: np.ndarray


def _first_lines(ctx: FrameContext, first: Measured) -> _FirstLines:
    """The first pass's streaks' flags, vectors and consensus voters."""
    comps = ctx.comps
    clipped = ctx.clipped(first.end_a, first.end_b)
    merged = ctx.merged(first.width_px, first.sigma_c)
    C = comps.ids.size
    v = first.end_b - first.end_a
    n_lines = np.bincount(first.own, minlength=C)
    single = n_lines[first.own] == 1
    voters = single & ~(first.crossing | first.looped | merged | clipped)
    return _FirstLines(clipped, merged, v, n_lines, voters)


@dataclass(frozen=True)
class _References:
    """Step 1: the frame's consensus field and the streaks the references are taken from
    (``R`` rows of ``refs``: the first pass's, or ``whole`` components', in which case
    ``field`` is theirs)."""

    field: Consensus
    refs: Measured
    #: References from whole components (:mod:`blurtrack.detect.separation.modal`).
    whole: bool
    #: ``(R,)`` bool: the references that agree with the field.
    good: np.ndarray
    #: ``(N,)`` px: each first-pass streak's deviation from the field.
    dev: np.ndarray
    #: ``(N,)`` px: its tolerance (:func:`~blurtrack.detect.separation.consensus.shape_tolerance`).
    tol: np.ndarray


def _references(
    ctx: FrameContext, first: Measured, lines: _FirstLines, field: Consensus | None
) -> _References | None:
    """Step 1: the references, from the first pass's streaks that agree with ``field`` or,
    with too few of them, from whole components; None where neither gives enough."""
    q = ctx.params.quality
    v = lines.v
    refs = first  # the streaks the references are taken from
    whole = False  # references from whole components (blurtrack.detect.separation.modal)
    good = np.zeros(len(first), bool)
    if field is not None:
        good = field.use & (field.dev <= 0.5 * shape_tolerance(field.c, q))
    if field is None or int(good.sum()) < q.min_reference:
        # Too few whole first-pass lines: references from whole components instead.
        alt = component_references(ctx, first.sigma_c, first.sigma_raw)
        if alt is None:
            return None
        # Whole components are references by their shape; their lines only need to agree.
        alt_good = alt[1].use & (alt[1].dev <= shape_tolerance(alt[1].c, q))
        if int(alt_good.sum()) < q.min_reference:
            return None
        (refs, field), good, whole = alt, alt_good, True
        cf = field.at(first.time_mid)
        dev = np.minimum(np.hypot(*(v - cf).T), np.hypot(*(v + cf).T))
        tol = shape_tolerance(cf, q)
    else:
        dev, tol = field.dev, shape_tolerance(field.c, q)
    return _References(field, refs, whole, good, dev, tol)


def _finish(
    ctx: FrameContext,
    first: Measured,
    lines: _FirstLines,
    refs: _References,
    m: Measured | None,
    replaced: np.ndarray | None,
) -> Separation:
    """With component references, their whole lines replace their components' lines
    where the first pass's were broken: a component whose one plain first-pass line
    agrees with the field keeps it (measured on the image itself)."""
    if not refs.whole:
        return Separation(m, replaced, refs.field)
    C = ctx.comps.ids.size
    clipped, n_lines = lines.clipped, lines.n_lines
    rep = np.zeros(C, bool) if replaced is None else replaced.copy()
    # Components all of whose reference lines agree with the field, and whose first pass
    # did not already measure them whole.
    bad = np.zeros(C, bool)
    bad[refs.refs.own[~refs.good]] = True
    fine = ~(clipped | first.crossing | first.looped) & (refs.dev <= refs.tol)
    bad[first.own[fine & (n_lines[first.own] == 1)]] = True
    rows = ~bad[refs.refs.own] & ~rep[refs.refs.own]
    rep[refs.refs.own[rows]] = True
    return Separation(combine(refs.refs, rows, m), rep, refs.field, refs.refs, refs.good)


@dataclass(frozen=True)
class _Candidates:
    """Step 2: the candidates and every component's nearest reference (``C`` components)."""

    #: ``(C,)`` bool: the candidates.
    cand: np.ndarray
    #: ``(C,)`` each component's nearest reference (a row of ``_References.refs``).
    nearest: np.ndarray
    #: ``(C,)`` bool: components holding a line far shorter than the consensus.
    stub: np.ndarray
    #: ``(C, 2)`` px: the centre of each component's box.
    centre: np.ndarray


def _candidates(
    ctx: FrameContext,
    first: Measured,
    folded: np.ndarray,
    lines: _FirstLines,
    refs: _References,
) -> _Candidates | None:
    """Step 2: the candidates (``folded``: the components the skeleton tracer took) and
    their nearest references; None where too few references are left or no candidate."""
    comps = ctx.comps
    sp, q = ctx.params.separation, ctx.params.quality
    clipped, merged, n_lines = lines.clipped, lines.merged, lines.n_lines
    field, whole = refs.field, refs.whole
    C = comps.ids.size
    bad_line = ~clipped & ((refs.dev > refs.tol) | first.crossing | first.looped | merged)
    cand = np.zeros(C, bool)
    cand[first.own[bad_line]] = True
    cand |= folded | (n_lines == 0)
    ref_idx = np.flatnonzero(refs.good)
    # A component is compared with its nearest references other than itself: a chain of two
    # streaks whose one line measured the first of them looks clean but has twice the area.
    ref_area = comps.areas[refs.refs.own[ref_idx]].astype(np.float64)
    x, y, w, h = comps.boxes.T.astype(np.float64)
    centre = np.stack([x + w / 2, y + h / 2], axis=1)
    ref_mid = refs.refs.time_mid[ref_idx]
    d2 = (centre[:, None, 0] - ref_mid[None, :, 0]) ** 2 + (
        centre[:, None, 1] - ref_mid[None, :, 1]
    ) ** 2
    d2[refs.refs.own[ref_idx], np.arange(ref_idx.size)] = np.inf
    k_near = min(sp.neighbours, ref_idx.size - 1)
    near = np.argpartition(d2, k_near - 1, axis=1)[:, :k_near]
    cand |= comps.areas > sp.area_factor * np.median(ref_area[near], axis=1)
    # (Whole components are references whatever their first-pass lines were.)
    keep_ref = np.full(ref_idx.size, True) if whole else ~cand[refs.refs.own[ref_idx]]
    if int(keep_ref.sum()) < q.min_reference:
        return None
    ref_idx, ref_mid, d2 = ref_idx[keep_ref], ref_mid[keep_ref], d2[:, keep_ref]
    # Every component's nearest reference (local: the streaks' shape varies over the frame).
    nearest = ref_idx[np.argmin(d2, axis=1)]
    cand[refs.refs.own[ref_idx]] = False
    # One plain line in a component of about a reference's area is one streak measured a
    # little off: no template can split or join it.
    plain_one = np.zeros(C, bool)
    plain_one[first.own[~(first.crossing | first.looped | merged)]] = True
    ratio = comps.areas / comps.areas[refs.refs.own[nearest]]
    # ... unless that line is far shorter than the consensus (a measurement that collapsed).
    stub = np.zeros(C, bool)
    c_len = np.hypot(*field.at(first.time_mid).T)
    stub_rows = (c_len >= sp.stub_min_px) & (first.length_px < sp.stub_fraction * c_len)
    stub[first.own[stub_rows]] = True
    cand &= ~(plain_one & ~stub & (n_lines == 1) & ~folded & (ratio > 0.75) & (ratio < 1.3))
    if not cand.any():
        return None
    return _Candidates(cand, nearest, stub, centre)


@dataclass(frozen=True)
class _Pursuit:
    """Step 3's pursuit: the placements, the candidates' light (``light``, the frame's shape,
    float32) and what the placements leave of it (``residual``); ``pix_cand``: ``(n_px,)``
    bool, the component pixels that are the candidates'."""

    placements: list[Placement]
    light: np.ndarray
    residual: np.ndarray
    pix_cand: np.ndarray


def _pursue_candidates(ctx: FrameContext, refs: _References, cands: _Candidates) -> _Pursuit:
    """Step 3: the matching pursuit of each candidate (the largest first) with its nearest
    reference's template, mapped onto the local consensus."""
    smooth, signal, comps = ctx.smooth, ctx.signal, ctx.comps
    sp = ctx.params.separation
    field, whole, cand, nearest = refs.field, refs.whole, cands.cand, cands.nearest
    C = comps.ids.size
    # Residual image: the candidates' light only (clean neighbours are not matched).
    is_cand = np.zeros(int(comps.labels.max()) + 1, bool)
    is_cand[comps.ids[cand]] = True
    pix_cand = np.repeat(cand, comps.areas)
    residual = np.zeros(smooth.shape, np.float32)
    residual[comps.ys[pix_cand], comps.xs[pix_cand]] = comps.values[pix_cand]
    light = residual.copy()
    templates: dict[tuple[int, int, int], Template] = {}
    bases: dict[int, Template] = {}
    local = field.at(cands.centre)
    placements: list[Placement] = []
    order = np.flatnonzero(cand)
    order = order[np.argsort(-comps.areas[order], kind="stable")]
    comp_of_label = np.full(is_cand.size, -1, np.int64)
    comp_of_label[comps.ids] = np.arange(C)
    where = PursuitFrame(comps, comp_of_label)
    for ci in order.tolist():
        k = int(nearest[ci])
        # The reference mapped onto the local consensus by a rotation and scaling.
        vk = complex(*field.at(refs.refs.time_mid[k : k + 1])[0])
        zt = complex(*local[ci])
        z = zt / vk if (zt / vk).real > 0 else -zt / vk
        if not 0.7 < abs(z) < 1.4:
            continue
        key = (k, round(abs(z) / 0.02), round(float(np.angle(z)) / 0.02))
        if key not in templates:
            if k not in bases:
                bases[k] = template(
                    smooth, signal, comps, int(refs.refs.own[k]), refs.refs.points[k]
                )
            base = bases[k]
            templates[key] = similar(base, z, refs.refs.time_mid[k]) if abs(z - 1) > 0.02 else base
        halo = sp.halo_max_whole if whole else sp.halo_max
        placements += pursue(residual, where, ci, templates[key], sp, halo)
    return _Pursuit(placements, light, residual, pix_cand)


def _replaced(
    ctx: FrameContext,
    first: Measured,
    lines: _FirstLines,
    refs: _References,
    cands: _Candidates,
    pur: _Pursuit,
) -> tuple[np.ndarray, list[Placement]]:
    """Step 3: the joint fit of the placements, the ``(C,)`` bool candidates they replace
    and those candidates' placements."""
    smooth, comps = ctx.smooth, ctx.comps
    sp = ctx.params.separation
    cand, pix_cand, light, residual = cands.cand, pur.pix_cand, pur.light, pur.residual
    C = comps.ids.size
    # Placements that share light are fitted together (streaks running along each other);
    # not with whole-component references: real lights on a string differ more from their
    # template than the pair's fit can tell (night2: 61 whole streaks without, 55 with).
    placements, model = (pur.placements, None) if refs.whole else refit(light, pur.placements, sp)
    if model is not None:
        residual = np.maximum(light - model, 0.0)
    # Candidates whose light the placements mostly explain are replaced.
    before = np.zeros(C)
    after = np.zeros(C)
    ci_pix = np.repeat(np.arange(C), comps.areas)[pix_cand]
    vals = comps.values[pix_cand]
    res = residual[comps.ys[pix_cand], comps.xs[pix_cand]].astype(np.float64)
    before += np.bincount(ci_pix, vals * vals, C)
    after += np.bincount(ci_pix, res * res, C)
    # Components at the border keep parts that no placement can explain (streaks leaving
    # the frame): one placement is enough there.
    x, y, w, h = comps.boxes.T
    H, W = smooth.shape
    border = (x == 0) | (y == 0) | (x + w == W) | (y + h == H)
    explained = np.zeros(C, bool)
    explained[[p.comp for p in placements]] = True
    replaced = cand & ((after <= sp.residual_max * before) | (border & explained))
    # A candidate explained by one placement of its own, whose first pass gave one plain
    # line, is one streak: its first measurement (on the image itself) stands.
    n_place = np.bincount([p.comp for p in placements], minlength=C)
    plain = np.zeros(C, bool)
    plain[first.own[~(first.crossing | first.looped)]] = True
    replaced &= ~((n_place == 1) & (lines.n_lines == 1) & plain & ~cands.stub)
    placements = [p for p in placements if replaced[p.comp]]
    return replaced, placements


def _measure(ctx: FrameContext, first: Measured, placements: list[Placement]) -> Measured:
    """Step 4: each placement's line measured on its own image (the mosaic), in frame
    coordinates."""
    sp = ctx.params.separation
    pad = int(np.ceil(6.0 * first.sigma_c)) + 8
    mos_s, mos_r, lines, back = placement_mosaic(ctx.smooth, ctx.signal, placements, pad)
    ls = LineSet(
        lines=lines,
        owner=[p.comp for p in placements],
        crossing=overlapping_placements(placements, sp.overlap_fraction).tolist(),
        looped=[False] * len(placements),
    )
    m = measure_lines(ctx.on(mos_s, mos_r), ls, first.sigma_c, False, first.sigma_raw)
    off = back[m.src]
    m.end_a = m.end_a + off
    m.end_b = m.end_b + off
    m.time_mid = m.time_mid + off
    m.points = [pt + o for pt, o in zip(m.points, off, strict=True)]
    return m
