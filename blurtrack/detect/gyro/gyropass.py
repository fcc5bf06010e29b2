"""Second detection pass with the gyro's predicted streak shape as the template.

The first pass (:func:`blurtrack.detect.frame.detect_frame`) works from the image alone; its
template separation (:mod:`blurtrack.detect.separation.separate`) takes the frame's own clean
streaks as templates. Where the shake reverses within the exposure every dot draws a *hairpin* (it
comes back a few px beside its own trail): each component is one wedge whose first-pass line is the
mean of both arms, every streak of the frame is alike, so the image consensus agrees with the
wrong lines and no image template corrects them. Once the session's time shift is found the
blur model predicts every dot's curve (:mod:`blurtrack.detect.gyro.gyrocurve`), and that curve,
rendered with the frame's cross-section and brightness, is the template.

Frames are refined where the prediction says the first pass cannot be right
(:func:`~blurtrack.detect.gyro.gyrogate.gate`, which says why: a hairpin frame, a long
first-pass streak far from its prediction, hooks, or, with the session's corrected model and
the time law, vectors the gyro's check would refuse). Other frames are returned untouched
(``clean``: bit-identical tables).

1. **Candidates** (:mod:`blurtrack.detect.gyro.gyrocandidates`; at least
   ``gyro_pass.min_arc_px`` of predicted arc; components touching
   the border too, ``gyro_pass.border_candidates``): in a
   hairpin frame every component whose predicted curve, placed with its light centroid on
   the component's, is a hairpin; in a frame let through for its hooks every component whose
   curve hooks; for its vectors, those holding a line whose vector misses; elsewhere every
   component. A first-pass line within
   ``tol_px + tol_rel * arc`` of its placed curve is no proof of its ends (a path that hooks
   inside a saturated end: the first pass's line runs straight into the blob); such a
   component (one line, so one dot) gets one placement of its own template and no sweep,
   and its line stays only where it fits the placed curve ``old_lines_margin`` times better
   than the new one (step 5).
2. **Shape**: the session normally corrects its nominal calibration before the pass
   (:mod:`blurtrack.detect.gyro.sessioncalib`: intrinsics, ``R_cam_imu``, time offset, readout
   and gyro bias fitted to the first pass's ``quality_ok`` streaks), and the predicted curve
   is the template as it is. Where it could not (``gyro_pass.shape_search``), the curve is off
   by a px or two: per candidate it is rotated and scaled about its centroid, a coordinate
   search ranked by the correlation normalised over the template's support and halo
   (:func:`blurtrack.detect.gyro.gyroshape.best_shape`). Shifts are searched by the matched
   filter over the component's box and by the joint fit (up to 8 px).
3. **Pursuit and joint fit** with that template, exactly as in separation
   (:func:`blurtrack.detect.separation.pursuit.pursue`,
   :func:`blurtrack.detect.separation.refit.refit`); then up to :data:`SWEEPS` more pursuits of
   every candidate's template but a one-line component's (step 1) over what the refitted
   placements leave, each followed by the joint
   refit of all (:func:`_sweep`); components whose light the placements explain are candidates for
   replacement. Where a candidate touches the border the images are padded with zeros beyond the
   frame and a placement may reach past it (``gyro_pass.clip_at_border``: scored and scaled by its
   template's part inside the frame, its placed curve cut at the border,
   :func:`~blurtrack.detect.gyro.gyroconfirm.cut_at_border`): chains into the border hold streaks
   leaving the frame, which no template wholly inside explains.
4. **Measurement** on each placement's own image (the mosaic of separation), with the placed
   curve as the coarse centre line, by :func:`blurtrack.detect.lines.measure.measure_lines`
   (:mod:`blurtrack.detect.gyro.gyromeasure`; hairpins as two arms): the ends, midpoints and
   profiles are the image's, not the prediction's. The prior decides *segmentation* (which
   light is which dot's, which way its line runs), not the endpoints, so calibration from
   these streaks is not circular; the one bounded exception is a short (or resting) streak's
   time law, how its light is spread between ends the image places
   (:mod:`blurtrack.detect.lines.lawfit`, ``gyro_pass.time_law``). (Each placement is
   measured on two own images, the neighbours' templates subtracted as they are and clipped
   at zero, and keeps the line nearer its placed curve, ``gyro_pass.clip_choice``: a choice
   between two segmentations, both lines the image's.)
5. **Refusal**: a placement whose measured ends lie farther than the tolerance from its
   placed curve's (and whose shape does not match it within twice that,
   :func:`~blurtrack.detect.gyro.gyroconfirm.confirmed`)
   is dropped (its component keeps its first-pass lines), and a component
   keeps its first-pass lines only where they fit the placed curves ``old_lines_margin``
   times better than the new streaks (per placement, the nearest old line against the new
   one); a frame where fewer than
   ``gyro_pass.accept_min`` of the measured placements survive keeps
   its first pass entirely (a wrong prior, e.g. a gyro of the wrong sign, draws shapes the
   image does not hold; :mod:`blurtrack.detect.gyro.gyroaccept` runs steps 4 and 5,
   :mod:`blurtrack.detect.gyro.gyroconfirm` holds their tests).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.context import FrameContext, prepare_and_segment
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyroaccept import (
    accepted_components,
    first_pass_kept,
    keep_old_lines,
    measure,
)
from blurtrack.detect.gyro.gyrocandidates import (
    Candidates,
    Canvas,
    TemplateProfile,
    candidate_canvas,
    candidates,
    template_profile,
)
from blurtrack.detect.gyro.gyrogate import gate, vectors_missed
from blurtrack.detect.gyro.gyromeasure import as_streaks
from blurtrack.detect.gyro.gyroshape import best_shape
from blurtrack.detect.lines.measure import combine
from blurtrack.detect.params import DetectParams, GyroPassParams, SeparationParams
from blurtrack.detect.separation.pursuit import PursuitFrame, pursue
from blurtrack.detect.separation.refit import model_image, refit
from blurtrack.detect.separation.templates import InsideNorms, Placement, Template
from blurtrack.detect.session.orientation import FrameTiming

#: More pursuits over what the placements leave (:func:`_sweep`). The first pursuit of a
#: component stops after ``MAX_ROUNDS`` or where its tries fail the halo test, which a
#: neighbour's still unexplained light fails; once the neighbours are placed and the joint
#: refit has moved them, some of the dots left over pass it. On `hard` seed 2 (10 frames),
#: 44 of the 102 missed dots inside components the pass replaced had no placement within 8 px
#: (session 2026-12-04, third). 0: none.
SWEEPS = 2


def _sweep(
    light: np.ndarray,
    residual: np.ndarray,
    placements: list[Placement],
    templates: dict[int, Template],
    where: PursuitFrame,
    sp: SeparationParams,
) -> tuple[list[Placement], np.ndarray]:
    """Up to :data:`SWEEPS` more pursuits of each of ``templates`` over the light the
    placements so far (jointly refitted) leave, each followed by the joint refit of all:
    the placements and the residual (``where``: the frame's components, and the norms of
    :func:`~blurtrack.detect.separation.templates.inside_norm2` over ``where.inside``,
    remembered over the pursuits and refits of the frame)."""
    for _ in range(SWEEPS):
        if not placements:
            break
        more: list[Placement] = []
        for c, tpl in templates.items():
            more += pursue(residual, where, c, tpl, sp, sp.halo_max)
        if not more:
            break
        placements, model_img = refit(light, placements + more, sp, where.inside, where.norms)
        if model_img is not None:
            residual = np.maximum(light - model_img, 0.0)
    return placements, residual


@dataclass(frozen=True)
class FrameOutcome:
    """What the pass did with one frame: ``status`` ``skipped`` (nothing to refine, no
    candidate), ``refused`` (the prior did not fit), ``refined``; the number of candidate
    components, replaced components and new streaks."""

    status: str
    candidates: int = 0
    replaced: int = 0
    streaks: int = 0


def refine_frame(
    image: np.ndarray | Callable[[], np.ndarray],
    fs: FrameStreaks,
    timing: FrameTiming,
    model: Any,
    params: DetectParams | None = None,
    sigma_c: float | None = None,
    gate_curves: list[np.ndarray] | None = None,
    vector_tol_px: float | None = None,
) -> tuple[FrameStreaks, FrameOutcome]:
    """The second pass on one frame (see the module text): the frame's streaks (``fs`` itself
    when nothing changed) and what happened. ``image``: the frame as stored, or a function
    that reads it (called only when the gate lets the frame through). ``model``: a
    :class:`blurtrack.geometry.blur_model.BlurModel` (or anything with its ``camera``,
    ``orientation_grid`` and ``point_track_ordered``) covering the frame. ``sigma_c``: the
    smoothed cross-section sigma of the templates and the measurement (None: the frame's,
    ``fs.sigma_c_px``).
    ``gate_curves``: gets the :func:`gate`'s curves of ``fs``'s streaks inside the frame.
    ``vector_tol_px``: where ``model`` is the session's corrected one, the check's vector
    tolerance, for the gate's ``vectors`` test (None: not tested)."""
    p = params or DetectParams()
    gp, sp = p.gyro_pass, p.separation
    curves_seen: list[np.ndarray] = [] if gate_curves is None else gate_curves
    reason = gate(fs, timing, model, gp, curves_seen, p.source.hairpin_depth_px, vector_tol_px)
    if reason is None:
        return fs, FrameOutcome("skipped")
    ctx = _frame_context(image, p)
    # 1. Candidates.
    off = None
    if reason == "vectors":
        assert vector_tol_px is not None  # the gate tests the vectors only with a tolerance
        off = vectors_missed(fs, curves_seen[-1], vector_tol_px)
    cands = candidates(ctx, fs, timing, model, gp, reason, p.source.hairpin_depth_px, off)
    if cands is None:
        return fs, FrameOutcome("skipped")
    n_cand = cands.n_cand
    # 2. Shape (the templates' cross-sections and light; the images, padded at the border).
    prof = template_profile(ctx, fs, cands, p, sigma_c)
    canvas = candidate_canvas(ctx, cands, prof, gp)
    # 3. Pursuit of each candidate's template, joint fit and sweeps.
    pur = _pursue_candidates(cands, canvas, prof, gp, sp)
    if not pur.placements:
        return fs, FrameOutcome("refused", n_cand)
    placements, residual = _joint_fit(canvas, pur, sp)
    replaced, placements = _explained(cands, canvas, placements, residual, sp)
    if not placements:
        return fs, FrameOutcome("refused", n_cand)
    # 4. Measurement on each placement's own image.
    meas = measure(ctx, cands, placements, prof, gp)
    # 5. Refusal; first-pass lines kept where they fit better.
    whole = accepted_components(cands, meas, replaced, placements, gp)
    if whole is None:
        return fs, FrameOutcome("refused", n_cand)
    whole = keep_old_lines(fs, cands, meas, whole, gp)
    m = combine(meas.m, whole[meas.m.own] & meas.good)
    keep_old = first_pass_kept(fs, timing, model, cands, whole, gp, sp)
    out = as_streaks(fs, keep_old, m, ctx, prof.sig_s_px)
    return out, FrameOutcome("refined", n_cand, int(whole.sum()), len(m))


def _frame_context(image: np.ndarray | Callable[[], np.ndarray], p: DetectParams) -> FrameContext:
    """The frame prepared as the first pass prepares it (``image``: the frame as stored, or a
    function that reads it)."""
    if callable(image):
        image = image()
    return prepare_and_segment(image, p)[1]


def _shape(
    c: int,
    cands: Candidates,
    canvas: Canvas,
    prof: TemplateProfile,
    gp: GyroPassParams,
    sp: SeparationParams,
) -> Template | None:
    """Step 2: candidate ``c``'s template (padded coordinates, with its unsmoothed image);
    None where the shape search (``gyro_pass.shape_search``) finds none that fits."""
    P = canvas.pad_px
    if gp.shape_search:
        tpl, score = best_shape(
            canvas.light,
            canvas.comps,
            c,
            cands.pts_px[c] + P,
            prof.template,
            sp.inside_min,
            canvas.in_frame,
        )
        if tpl is None or score < gp.shape_score_min:
            return None
        return prof.template(tpl.points, with_raw=True)  # the same, with its unsmoothed image
    # The session-corrected curve as predicted: the pursuit's own floors (correlation,
    # amplitude, halo) decide where it fits; a trial of its one shape first ranked the
    # same placements again (hard seeds 1-11: the same tables within 0.2 points, 10 %
    # less CPU).
    return prof.template(cands.pts_px[c] + P, with_raw=True)


@dataclass(frozen=True)
class _Pursuit:
    """Step 3's first pursuit: the placements (padded coordinates), the light they leave
    (``residual``, as ``Canvas.light``), the templates the sweeps pursue again (by
    component) and what the frame's pursuits share, with the norms remembered over them and
    the refits (``where``)."""

    placements: list[Placement]
    residual: np.ndarray
    templates: dict[int, Template]
    where: PursuitFrame


def _pursue_candidates(
    cands: Candidates,
    canvas: Canvas,
    prof: TemplateProfile,
    gp: GyroPassParams,
    sp: SeparationParams,
) -> _Pursuit:
    """Step 3: the pursuit of each candidate's template (:func:`_shape`), the largest
    components first; a one-dot component's for one placement."""
    comps = cands.comps
    residual = canvas.light.copy()
    placements: list[Placement] = []
    order = np.flatnonzero(cands.cand)
    order = order[np.argsort(-comps.areas[order], kind="stable")]
    templates: dict[int, Template] = {}  # the shapes the sweeps pursue again
    # The sweeps pursue and refit over the same regions again: the norms remembered.
    where = PursuitFrame(
        canvas.comps, canvas.comp_of_label, canvas.in_frame, InsideNorms(canvas.in_frame)
    )
    for c in order.tolist():
        tpl = _shape(c, cands, canvas, prof, gp, sp)
        if tpl is None:
            continue
        limit = 1 if cands.one_dot[c] else None
        if limit is None:
            templates[c] = tpl
        placements += pursue(residual, where, c, tpl, sp, sp.halo_max, limit)
    return _Pursuit(placements, residual, templates, where)


def _joint_fit(
    canvas: Canvas, pur: _Pursuit, sp: SeparationParams
) -> tuple[list[Placement], np.ndarray]:
    """Step 3: the joint refit of the pursuit's placements, then the sweeps (:func:`_sweep`):
    the placements and the light they leave (padded coordinates)."""
    light, where = canvas.light, pur.where
    residual = pur.residual
    placements, model_img = refit(light, pur.placements, sp, where.inside, where.norms)
    if model_img is not None or SWEEPS:
        # (Where the refit moved nothing the sweep starts from the placements' sub-pixel
        # templates, as the refit paints them, not the pursuit's integer ones.)
        model_img = model_image(light, placements) if model_img is None else model_img
        residual = np.maximum(light - model_img, 0.0)
    return _sweep(light, residual, placements, pur.templates, where, sp)


def _explained(
    cands: Candidates,
    canvas: Canvas,
    placements: list[Placement],
    residual: np.ndarray,
    sp: SeparationParams,
) -> tuple[np.ndarray, list[Placement]]:
    """Step 3: the ``(C,)`` bool candidates whose light the placements explain
    (``separation.residual_max``) and their placements, in frame coordinates."""
    comps, pix, pix_cand = cands.comps, cands.pix, canvas.pix_cand
    C = comps.ids.size
    P = canvas.pad_px
    vals = comps.values[pix_cand]
    res = residual[canvas.comps.ys[pix_cand], canvas.comps.xs[pix_cand]].astype(np.float64)
    before = np.bincount(pix[pix_cand], vals * vals, C)
    after = np.bincount(pix[pix_cand], res * res, C)
    replaced = cands.cand & (after <= sp.residual_max * before)
    # Back to frame coordinates (a template's box plus its shift).
    placements = [
        Placement(q.tpl, q.shift - P, q.amp, q.comp) for q in placements if replaced[q.comp]
    ]
    return replaced, placements
