"""Steps 4 and 5 of the gyro-template pass (:mod:`blurtrack.detect.gyro.gyropass`): each
placement measured on its own image and checked against its placed curve, which components
the frame replaces whole (or none: the frame keeps its first pass), and which first-pass
lines stay (where they fit the placed curves clearly better, and not remnants or unsplit
chains). Pixels as DESIGN's; ends ``(N, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyrocandidates import Candidates, TemplateProfile, inside_frame
from blurtrack.detect.gyro.gyroconfirm import accepted, confirmed, cut_at_border, mismatch
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.gyromeasure import measure_placements
from blurtrack.detect.lines.measure import Measured
from blurtrack.detect.params import GyroPassParams, SeparationParams
from blurtrack.detect.separation.templates import Placement
from blurtrack.detect.session.orientation import FrameTiming


@dataclass(frozen=True)
class Measurement:
    """Step 4: the placements' measured lines (``m``, ``M`` rows; ``m.src`` indexes the
    placements, ``m.own`` their components) against their placed curves' ends."""

    m: Measured
    #: ``(M, 2)`` px: the placed curve's first end of each measured line.
    ps: np.ndarray
    #: ``(M, 2)`` px: its last end.
    pe: np.ndarray
    #: ``(M,)`` px: the end-to-end mismatch of each line and its placed curve.
    mis_new: np.ndarray
    #: ``(M,)`` bool: the image confirms the placed curve's shape.
    good: np.ndarray


def measure(
    ctx: FrameContext,
    cands: Candidates,
    placements: list[Placement],
    prof: TemplateProfile,
    gp: GyroPassParams,
) -> Measurement:
    """Step 4: each placement measured on its own image (frame coordinates) and checked
    against its placed curve."""
    H, W = ctx.shape
    # Each measured line against its placement's curve: the image must confirm the shape.
    # A placed curve reaching past the border is cut there (its line ends at the border).
    placed_ends = np.array([cut_at_border(q.tpl.points + q.shift, W, H) for q in placements])
    m = measure_placements(ctx, placements, placed_ends, prof.sig_s_px, prof.sig_r_px)
    ps, pe = placed_ends[m.src, 0].reshape(-1, 2), placed_ends[m.src, 1].reshape(-1, 2)
    mis_new = mismatch(m.end_a, m.end_b, ps, pe)
    good = confirmed(m.end_a, m.end_b, ps, pe, cands.tol_px[m.own], gp.shape_shift_factor)
    return Measurement(m, ps, pe, mis_new, good)


def accepted_components(
    cands: Candidates,
    meas: Measurement,
    replaced: np.ndarray,
    placements: list[Placement],
    gp: GyroPassParams,
) -> np.ndarray | None:
    """Step 5: ``(C,)`` bool, the components replaced whole; None where the frame keeps its
    first pass (``gyro_pass.accept_min``)."""
    C = cands.comps.ids.size
    m, good = meas.m, meas.good
    # Components replaced only where every placement of theirs was measured and confirmed.
    n_place = np.bincount([q.comp for q in placements], minlength=C)
    n_good = np.bincount(m.own[good], minlength=C)
    # A placement the measurement could not follow (no line on its own image) loses its dot,
    # not its component's other dots: chains into the border leave some such.
    n_meas = np.bincount(m.own, minlength=C)
    whole = replaced & (n_good == n_meas) & (n_meas > 0) & (n_meas >= gp.measured_min * n_place)
    if not accepted(int(n_good[whole].sum()), len(m), gp.accept_min):
        return None
    return whole


def keep_old_lines(
    fs: FrameStreaks,
    cands: Candidates,
    meas: Measurement,
    whole: np.ndarray,
    gp: GyroPassParams,
) -> np.ndarray:
    """Step 5: ``whole`` (``(C,)`` bool, a copy) less the components whose first-pass lines
    stay."""
    whole = whole.copy()
    C = cands.comps.ids.size
    own, n_lines, m = cands.own, cands.n_lines, meas.m
    # A component's first-pass lines stay where they fit its placed curves clearly better
    # (gyro_pass.old_lines_margin) than the new streaks: per placement, the nearest of the
    # component's old lines against its new line.
    has_old = np.flatnonzero(whole[m.own] & (n_lines[m.own] > 0))
    if has_old.size:
        lines = np.flatnonzero(own >= 0)
        old_best = np.full(has_old.size, np.inf)
        for j, r in enumerate(has_old.tolist()):
            li = lines[own[lines] == m.own[r]]
            k = np.full(li.size, r)
            old_best[j] = float(
                np.min(mismatch(fs.end_a[li], fs.end_b[li], meas.ps[k], meas.pe[k]))
            )
        comp = m.own[has_old]
        cost_old = np.bincount(comp, old_best, C)
        cost_new = np.bincount(comp, meas.mis_new[has_old], C)
        whole[comp[gp.old_lines_margin * cost_old[comp] <= cost_new[comp]]] = False
    return whole


def first_pass_kept(
    fs: FrameStreaks,
    timing: FrameTiming,
    model: Any,
    cands: Candidates,
    whole: np.ndarray,
    gp: GyroPassParams,
    sp: SeparationParams,
) -> np.ndarray:
    """Step 5: ``(N,)`` bool, the first-pass streaks that stay (those outside the components
    ``whole`` replaces, less remnants and unsplit chains)."""
    own = cands.own
    keep_old = ~((own >= 0) & whole[np.maximum(own, 0)])
    # A remaining first-pass spot far shorter than its predicted curve is a remnant (of a
    # chain, a blob), as frame.py drops those far shorter than the image consensus; a line
    # far longer is a chain of several dots' streaks that the pass could not split.
    inside = inside_frame(fs)
    pred_arc = np.zeros(len(fs))
    pred_arc[inside] = predict_curves(model, fs.time_mid[inside], timing.t_s, timing.exposure_s).arc
    long_pred = pred_arc >= sp.spot_min_px
    keep_old &= ~(long_pred & (fs.length_px < sp.spot_fraction * pred_arc))
    keep_old &= ~(long_pred & (fs.length_px > gp.chain_factor * pred_arc))
    return keep_old
