"""The gyro-template pass's candidates (:mod:`blurtrack.detect.gyro.gyropass`, steps 1 and 2):
which components of a frame the pass pursues, each with its predicted curve placed on its light,
what the frame's templates share (cross-sections, one dot's light, the saturation level) and the
candidates' light image, padded beyond the border where a candidate touches it."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.framecheck import hairpin_depth
from blurtrack.detect.gyro.gyroconfirm import mismatch
from blurtrack.detect.gyro.gyrocurve import Curves, curve_template, predict_curves
from blurtrack.detect.lines.segment import Components
from blurtrack.detect.params import DetectParams, GyroPassParams
from blurtrack.detect.separation.templates import HALO_PX, Template
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import CoverageError

#: Why the gate (:func:`~blurtrack.detect.gyro.gyrogate.gate`) lets a frame through: its
#: median predicted curve is a hairpin (``hairpin``: every component whose curve is one a
#: candidate), a long first-pass streak misses its prediction (``mismatch``: every long
#: component), or more than ``gyro_pass.hook_fraction`` of its long streaks hook (``hooks``:
#: the components whose curves hook), or, with the session's corrected model, more than that
#: fraction of their start-to-end vectors miss the prediction by the check's tolerance
#: (``vectors``: the components of those lines).
GateReason = Literal["hairpin", "mismatch", "hooks", "vectors"]


def inside_frame(fs: FrameStreaks) -> np.ndarray:
    """``(N,)`` bool: the first-pass streaks inside the frame (not ``clipped``)."""
    return ~fs.flags["clipped"] if len(fs) else np.zeros(0, bool)


def line_owner(fs: FrameStreaks, comps: Components) -> np.ndarray:
    """``(N,)`` component index of each first-pass streak (the component holding most of its
    centre line; -1 for none)."""
    lut = np.full(int(comps.labels.max()) + 1, -1, np.int64)
    lut[comps.ids] = np.arange(comps.ids.size)
    H, W = comps.labels.shape
    out = np.full(len(fs), -1, np.int64)
    for i, pts in enumerate(fs.points):
        ix = np.clip(np.rint(pts[:, 0]).astype(int), 0, W - 1)
        iy = np.clip(np.rint(pts[:, 1]).astype(int), 0, H - 1)
        own = lut[comps.labels[iy, ix]]
        own = own[own >= 0]
        if own.size:
            out[i] = int(np.bincount(own).argmax())
    return out


def one_dot_light(
    lw: np.ndarray, border: np.ndarray, n_lines: np.ndarray, light_quantile: float
) -> float:
    """One dot's light (smoothed image units summed over its pixels): the median over the
    components inside the frame of their light per first-pass line. Every dot spends the
    same exposure, so its light does not depend on its streak's length; a component's light
    alone (the former estimate, its 0.4 quantile) is several dots' where long streaks chain
    (hard seed 2 frame 8: 300 against 155 for the 23 components holding one true streak,
    so the pursuit saw every dot at amplitude 0.5, under ``separation.amp_min``). Without
    first-pass lines inside the frame: the ``light_quantile`` quantile of the components'
    light (``gyro_pass.light_quantile``; chains are brighter)."""
    ok = ~border & (n_lines > 0)
    if ok.any():
        return float(np.median(lw[ok] / n_lines[ok]))
    return float(np.quantile(lw[~border], light_quantile)) if (~border).any() else 0.0


def pad_px(curves: np.ndarray, sigma: float) -> int:
    """Padding (px) beyond the frame that holds any template of ``curves (N, S, 2)`` placed
    with a part inside the frame (its extent, the blur's margin and the halo, some slack for
    the shape search's scaling)."""
    ext = float(np.max(curves.max(axis=1) - curves.min(axis=1))) if curves.size else 0.0
    return int(np.ceil(1.1 * ext + 3.0 * sigma)) + HALO_PX + 8


@dataclass(frozen=True)
class Candidates:
    """Step 1: the frame's components, their placed predicted curves and which of them the
    pass pursues (``C`` components, ``N`` first-pass streaks, ``S`` samples per curve)."""

    comps: Components
    #: ``(n_px,)`` the component index of each of ``comps``' pixels.
    pix: np.ndarray
    #: ``(C,)`` each component's light (smoothed image units summed over its pixels).
    comp_light: np.ndarray
    #: ``(C,)`` bool: the component touches the frame's border.
    border: np.ndarray
    #: ``(C, S, 2)`` px: each component's predicted curve placed with its light centroid on
    #: the component's.
    pts_px: np.ndarray
    #: ``(C,)`` px: ``tol_px + tol_rel * arc`` of each placed curve.
    tol_px: np.ndarray
    #: ``(C,)`` bool: the candidates.
    cand: np.ndarray
    #: ``(C,)`` bool: components of one dot (one placement of their own template, no sweep).
    one_dot: np.ndarray
    #: ``(N,)`` the component of each first-pass streak (-1: none; :func:`line_owner`).
    own: np.ndarray
    #: ``(C,)`` the number of first-pass streaks of each component.
    n_lines: np.ndarray

    @property
    def n_cand(self) -> int:
        """The number of candidates."""
        return int(self.cand.sum())


def candidates(
    ctx: FrameContext,
    fs: FrameStreaks,
    timing: FrameTiming,
    model: Any,
    gp: GyroPassParams,
    reason: GateReason,
    hook_depth_px: float,
    vector_off: np.ndarray | None = None,
) -> Candidates | None:
    """Step 1 (see the module text): the candidates of a frame the gate let through
    (``reason``: why, :data:`GateReason`; ``hook_depth_px``: for ``hooks``, the depth over
    which a component's curve hooks, :func:`~blurtrack.detect.gyro.framecheck.hairpin_depth`);
    None where the frame has no component, the gyro does not cover it or no component is a
    candidate."""
    H, W = ctx.shape
    comps = ctx.comps
    C = comps.ids.size
    if C == 0:
        return None
    pix = np.repeat(np.arange(C), comps.areas)
    lw = np.bincount(pix, comps.values, C)
    centre = (
        np.stack(
            [
                np.bincount(pix, comps.values * comps.xs, C),
                np.bincount(pix, comps.values * comps.ys, C),
            ],
            axis=1,
        )
        / np.maximum(lw, 1e-12)[:, None]
    )
    x, y, w, h = comps.boxes.T
    border = (x == 0) | (y == 0) | (x + w == W) | (y + h == H)
    try:
        curves: Curves = predict_curves(model, centre, timing.t_s, timing.exposure_s)
    except CoverageError:
        return None
    # Each curve placed with its light centroid (its mean: uniform in time) on the component's.
    pts = curves.pts - curves.pts.mean(axis=1, keepdims=True) + centre[:, None, :]
    arc, chord = curves.arc, curves.chord
    long_ = (~border | gp.border_candidates) & (arc >= gp.min_arc_px)
    if reason == "hairpin":
        long_ &= chord < gp.hairpin_chord * arc
    elif reason == "hooks":  # only the components whose dots hook: the others' ends are right
        long_ &= hairpin_depth(curves.pts) > hook_depth_px
    # Every long component of a frame the gate lets through for a hairpin or a mismatch is a
    # candidate: a line that the first pass measured well stays (below: where it fits the
    # placed curve old_lines_margin times better than the new one). One first-pass line near
    # its placed curve is no proof of its ends: where the dot's path hooks inside a saturated
    # end, the first pass draws its line straight into the blob, an end 2 px off and well
    # within ``tol`` (``hard`` seed 11 frame 6). Such a component holds one dot: its own
    # template gets one placement (a second would slip along the line, its template still
    # mostly on the light) and no sweep.
    own = line_owner(fs, comps)
    if reason == "vectors" and vector_off is not None:
        # Only the components of lines whose vectors miss the prediction.
        hit = np.zeros(C, bool)
        hit[own[(own >= 0) & vector_off]] = True
        long_ &= hit
    cand = long_.copy()
    n_lines = np.bincount(own[own >= 0], minlength=C)
    tol = gp.tol_px + gp.tol_rel * arc
    one_dot = np.zeros(C, bool)
    if reason != "hairpin":
        one = own >= 0
        o = own[one]
        mis1 = mismatch(fs.end_a[one], fs.end_b[one], pts[o, 0], pts[o, -1])
        one_dot[o[mis1 <= tol[o]]] = True
        one_dot &= n_lines == 1
    if not cand.any():
        return None
    return Candidates(comps, pix, lw, border, pts, tol, cand, one_dot, own, n_lines)


@dataclass(frozen=True)
class TemplateProfile:
    """Step 2: what the frame's templates share, their cross-sections (px) and one dot's
    light (:func:`one_dot_light`); ``ceiling``: the saturation level (None: nothing saturated)."""

    #: The smoothed image's cross-section sigma.
    sig_s_px: float
    #: The unsmoothed one (the raw template's).
    sig_r_px: float
    dot_light: float
    ceiling: float | None

    def template(self, curve: np.ndarray, with_raw: bool = False) -> Template:
        """The template of the placed curve ``curve (S, 2)`` (px; with its unsmoothed image
        where ``with_raw``)."""
        return curve_template(
            curve, self.sig_s_px, self.sig_r_px, self.dot_light, self.ceiling, with_raw
        )


def template_profile(
    ctx: FrameContext,
    fs: FrameStreaks,
    cands: Candidates,
    p: DetectParams,
    sigma_c: float | None,
) -> TemplateProfile:
    """Step 2: the templates' cross-sections (``sigma_c``: the smoothed one, None: the
    frame's) and light."""
    # The smoothed image's cross-section and the unsmoothed one (the raw template).
    sig_s = fs.sigma_c_px if sigma_c is None else float(sigma_c)
    sig_r = float(np.sqrt(max(sig_s**2 - p.smooth_sigma_px**2, 0.25)))
    dot_light = one_dot_light(
        cands.comp_light, cands.border, cands.n_lines, p.gyro_pass.light_quantile
    )
    ceiling = ctx.saturation if ctx.sat_comp is not None else None
    return TemplateProfile(sig_s, sig_r, dot_light, ceiling)


@dataclass(frozen=True)
class Canvas:
    """The images the pursuit and the fits work on: the candidates' light, padded with
    ``pad_px`` px of zeros beyond the frame where a candidate touches the border (else 0)."""

    pad_px: int
    #: The components in the padded images' coordinates.
    comps: Components
    #: The frame in the padded images ``(x0, y0, x1, y1)`` (None: not padded).
    in_frame: tuple[int, int, int, int] | None
    #: ``(n_px,)`` bool: the component pixels that are the candidates'.
    pix_cand: np.ndarray
    #: ``(H + 2 pad_px, W + 2 pad_px)`` float32: the candidates' light.
    light: np.ndarray
    #: ``(max label + 1,)`` the component index of each label (-1: none).
    comp_of_label: np.ndarray


def candidate_canvas(
    ctx: FrameContext, cands: Candidates, prof: TemplateProfile, gp: GyroPassParams
) -> Canvas:
    """Steps 2 and 3: the candidates' light image, padded at the border
    (``gyro_pass.clip_at_border``)."""
    H, W = ctx.shape
    comps, cand, border = cands.comps, cands.cand, cands.border
    C = comps.ids.size
    # Border candidates: the images padded with zeros beyond the frame, so that a placement
    # may reach past the border (a streak leaving the frame: its curve cut at the border).
    sig = max(prof.sig_s_px, prof.sig_r_px)
    P = pad_px(cands.pts_px[cand], sig) if gp.clip_at_border and (cand & border).any() else 0
    comps_p = comps
    in_frame: tuple[int, int, int, int] | None = None  # the frame in the padded images
    if P:
        comps_p = replace(
            comps,
            labels=np.pad(comps.labels, P),
            ys=comps.ys + P,
            xs=comps.xs + P,
            boxes=comps.boxes + np.array([P, P, 0, 0], comps.boxes.dtype),
        )
        in_frame = (P, P, P + W, P + H)
    pix_cand = cand[cands.pix]
    light = np.zeros((H + 2 * P, W + 2 * P), np.float32)
    light[comps_p.ys[pix_cand], comps_p.xs[pix_cand]] = comps.values[pix_cand]
    comp_of_label = np.full(int(comps.labels.max()) + 1, -1, np.int64)
    comp_of_label[comps.ids] = np.arange(C)
    return Canvas(P, comps_p, in_frame, pix_cand, light, comp_of_label)
