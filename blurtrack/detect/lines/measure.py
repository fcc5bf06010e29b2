"""Measuring coarse centre lines: refinement, gap splits, widths, saturated profiles, endpoint
fits and trimming, all lines of a frame at once (one call per detection pass).

:func:`measure_lines` is what :func:`blurtrack.detect.frame.detect_frame` runs on the lines of
the segmentation (first pass) and again on the lines that template separation
(:mod:`blurtrack.detect.separation.separate`) places in its mosaic of separated streak images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.lines.centreline import (
    BILINEAR_VAR_PX2,
    RefinedLines,
    raw_flank_sigma,
    raw_profiles,
    refine_lines,
    trim_lines,
)
from blurtrack.detect.lines.endpoints import fit_edges, unclip_profiles
from blurtrack.detect.lines.gaps import split_at_gaps
from blurtrack.detect.lines.lawfit import LAW_SAMPLES
from blurtrack.detect.lines.ragged import Ragged, to_matrix

#: Share of a frame's measured lines under ``1 / source.point_width_ratio`` of its sigma from
#: which they are a population of point lights narrower than its median line
#: (:func:`_narrower_than_frame`): 0-2 % of the lines of the simulated laser frames (cut at
#: the border, or noise; `hard`, `hard_long_dense_grid`, `dense`, `realistic`) and of the two
#: string-light photographs, 12-27 % of the night photographs of lit facades, windows and
#: glare (night4-6).
NARROW_SHARE = 0.1


@dataclass
class LineSet:
    """Coarse lines with their bookkeeping: ``owner`` (component index), ``crossing`` and
    ``looped`` per line; ``lines`` a list of ``(n, 2)`` arrays or a :class:`Ragged`.
    ``law``: per line, None or the predicted time law of its streak
    (:func:`~blurtrack.detect.lines.lawfit.time_law`, oriented from the line's first point):
    a short streak with one is fitted under it (:func:`~blurtrack.detect.lines.lawfit.fit_law`),
    and a longer one unsaturated and not crossing where its dot rests near an end."""

    lines: Ragged | list[np.ndarray]
    owner: list[int]
    crossing: list[bool]
    looped: list[bool]
    law: list[np.ndarray | None] | None = None


@dataclass
class Measured:
    """Measured streaks (rows kept: ``N``), in the coordinates of the image measured on.

    ``own``: component index per streak; ``src``: index of the input line it came from;
    ``sigma_c``: the cross-section sigma used (measured from the widths unless fixed);
    ``sigma_raw``: that of the unsmoothed signal (saturated streaks); ``width_unmeasured``
    below; the rest as in :class:`~blurtrack.detect.frame.FrameStreaks`.
    """

    own: np.ndarray
    src: np.ndarray
    end_a: np.ndarray
    end_b: np.ndarray
    time_mid: np.ndarray
    plateau: np.ndarray
    length_px: np.ndarray
    width_px: np.ndarray
    points: list[np.ndarray]
    profile: list[np.ndarray]
    saturated: np.ndarray
    crossing: np.ndarray
    looped: np.ndarray
    short: np.ndarray
    sigma_c: float
    sigma_raw: float
    #: ``(N,)`` bool: streaks whose width no cross-section gives (``width_px`` NaN: the two
    #: arms of a hairpin with a blown-out arm, :mod:`blurtrack.detect.gyro.gyromeasure`);
    #: None: not recorded (the first pass), none such.
    width_unmeasured: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.own.size)


def measure_lines(
    ctx: FrameContext,
    ls: LineSet,
    sigma_c: float,
    measure_sigma: bool,
    sigma_raw: float | None = None,
    lit_median_factor: float | None = None,
) -> Measured:
    """Refine, split, fit and trim the lines of ``ls`` on ``ctx.smooth`` (and, for lines of
    saturated components, ``ctx.sat_comp[owner]``, the unsmoothed ``ctx.signal``).

    ``sigma_c``: guess of the smoothed cross-section sigma, replaced by the lines' median width
    when ``measure_sigma``; ``sigma_raw``: the unsmoothed sigma of saturated streaks (None:
    from the unsaturated widths); ``lit_median_factor``: see
    :func:`blurtrack.detect.lines.centreline.refine_lines`."""
    smooth, signal, saturation, sat_comp = ctx.smooth, ctx.signal, ctx.saturation, ctx.sat_comp
    smooth_sigma = ctx.smooth_sigma_px
    ceiling = saturation if sat_comp is not None and sat_comp.any() else None
    lp = ctx.params.lines
    ref = refine_lines(smooth, ls.lines, sigma_c, lp, ceiling, lit_median_factor)
    ref, parent = split_at_gaps(ref, lp)
    owner = np.asarray(ls.owner, np.int64)[parent]
    crossing = np.asarray(ls.crossing, bool)[parent]
    looped = np.asarray(ls.looped, bool)[parent]
    finite = ref.width[np.isfinite(ref.width)]
    if measure_sigma and finite.size:
        sigma_c = float(np.median(finite))
    lens = ref.lines.sizes
    A = to_matrix(ref.profile, lens)
    line_sat = np.zeros(lens.size, bool)
    sig_raw = sigma_c if sigma_raw is None else sigma_raw
    if sat_comp is not None and sat_comp.any():
        line_sat = sat_comp[owner]
        sat_lines = Ragged(ref.lines.points[line_sat[ref.lines.line_of]], lens[line_sat])
        if sigma_raw is None:
            clean = ref.width[~line_sat]
            clean = clean[np.isfinite(clean)]
            # Saturated streaks: width from the unsaturated ones if there are enough of
            # them, else from everyone's flanks (refine_lines measured clipped sections).
            flanks = None
            if clean.size < 8:
                flanks = raw_flank_sigma(signal, sat_lines, sigma_c, saturation)
                clean = ref.width[np.isfinite(ref.width)]
            sig_c = float(np.median(clean)) if clean.size else sigma_c
            sig_raw = float(np.sqrt(max(sig_c**2 - smooth_sigma**2, 0.25)))
            # The clipped sections read the sigma too wide, never too narrow: their sigma
            # bounds the flanks' (a flank fit above it holds a neighbour's light;
            # hard_long_exposure 103 frame 1, streaks piled on each other: 24.7 px).
            if flanks is not None:
                sig_raw = min(sig_raw, flanks)
            if measure_sigma:
                sigma_c = sig_c
    # Lines far narrower than the frame's sigma: their own width is their point spread.
    narrow = _narrower_than_frame(ref.width, sigma_c, ctx.params.source.point_width_ratio)
    own_raw = _narrow_raw_sigma(ctx, ref, narrow & line_sat, sig_raw)
    # Clipping happens before smoothing, so undo it on profiles of the unsmoothed signal
    # (there the clipped cross-section integral is an exact function of the true one).
    if line_sat.any():  # only saturated lines are sampled (rows past their ends stay 0)
        raw = to_matrix(raw_profiles(signal, sat_lines, sigma_c), sat_lines.sizes)
        sat_rows = np.flatnonzero(line_sat)
        own_rows = narrow[sat_rows]
        for rows, sigma in ((~own_rows, sig_raw), (own_rows, own_raw)):
            if rows.any():
                A[sat_rows[rows], : raw.shape[1]] = unclip_profiles(raw[rows], saturation, sigma)
    # Raw profiles are sampled bilinearly, which blurs by about 1/6 px^2 more.
    sat_sigma = np.where(narrow, own_raw, sig_raw)
    edge_sigma = np.where(
        line_sat,
        np.sqrt(sat_sigma**2 + BILINEAR_VAR_PX2),
        np.where(narrow, ref.width, sigma_c),
    )
    fit = fit_edges(A, lens, edge_sigma / ref.step, _laws(ls, ref, parent), ~line_sat & ~crossing)
    pos_a = np.where(fit.valid, fit.pos_a, 0.0)
    pos_b = np.where(fit.valid, fit.pos_b, 1.0)
    trimmed = trim_lines(ref, pos_a, pos_b, edge_sigma / ref.step)
    keep = np.flatnonzero(fit.valid)
    return Measured(
        own=owner[keep],
        src=parent[keep],
        end_a=trimmed.end_a[keep],
        end_b=trimmed.end_b[keep],
        time_mid=trimmed.time_mid[keep],
        plateau=np.stack([fit.plateau_a, fit.plateau_b], axis=1)[keep],
        length_px=trimmed.length_px[keep],
        width_px=ref.width[keep],
        points=[trimmed.points[k] for k in keep],
        profile=[trimmed.profile[k] for k in keep],
        saturated=line_sat[keep],
        crossing=crossing[keep],
        looped=looped[keep],
        short=fit.short[keep],
        sigma_c=sigma_c,
        sigma_raw=sig_raw,
    )


def _narrower_than_frame(width: np.ndarray, sigma_c: float, point_ratio: float) -> np.ndarray:
    """``(N,)`` bool: lines whose measured cross-section sigma ``width`` (smoothed image, NaN:
    not measured) is under ``sigma_c / point_ratio``. No point light is narrower than the
    optics' spread, so the frame's sigma (the median of its lines' widths) is not their
    spread: in a photograph whose lit facades, windows or glare outnumber its point lights,
    the median is theirs. Measured with it, a short light's ends are fitted as a blurred dot
    (night5's distant lamps, 12-15 px streaks: 0.1-2 px long) or not at all; their own width
    fits them. On a laser frame every dot's width lies within a few per cent of the median,
    so none is narrow but a line cut short at the border or lost in noise: such a frame's
    narrow lines are artefacts, no more than :data:`NARROW_SHARE` of its measured lines."""
    w = np.asarray(width, float)
    narrow = np.isfinite(w) & (w < sigma_c / point_ratio)
    if np.count_nonzero(narrow) < NARROW_SHARE * np.count_nonzero(np.isfinite(w)):
        return np.zeros(w.size, bool)
    return narrow


def _narrow_raw_sigma(
    ctx: FrameContext, ref: RefinedLines, rows: np.ndarray, frame_raw: float
) -> float:
    """The unsmoothed sigma of the saturated narrow lines ``rows`` (``(N,)`` bool over
    ``ref``'s lines): their flanks' (:func:`raw_flank_sigma`), bounded by their median
    clipped width less the smoothing (which reads too wide, never too narrow) and by the
    frame's ``frame_raw``; ``frame_raw`` where no line is such."""
    if not rows.any():
        return frame_raw
    w = ref.width[rows]
    bound = float(np.sqrt(max(float(np.median(w)) ** 2 - ctx.smooth_sigma_px**2, 0.25)))
    sizes = ref.lines.sizes
    lines = Ragged(ref.lines.points[rows[ref.lines.line_of]], sizes[rows])
    flanks = raw_flank_sigma(ctx.signal, lines, float(np.median(w)), ctx.saturation)
    return min(bound, frame_raw) if flanks is None else min(flanks, bound, frame_raw)


def _laws(ls: LineSet, ref: RefinedLines, parent: np.ndarray) -> np.ndarray | None:
    """``(N, LAW_SAMPLES)`` time laws of the refined lines (NaN rows: none), oriented along
    each refined line; None where no line has one. A line cut at a gap has none: the law is
    its whole streak's."""
    if ls.law is None or not any(x is not None for x in ls.law):
        return None
    n_of = np.bincount(parent, minlength=len(ls.law))
    first = ref.lines.points[ref.lines.starts]
    coarse_lines = ls.lines if isinstance(ls.lines, list) else ls.lines.split()
    out = np.full((parent.size, LAW_SAMPLES), np.nan)
    for i, j in enumerate(parent.tolist()):
        law = ls.law[j]
        if law is None or n_of[j] != 1:
            continue
        coarse = np.asarray(coarse_lines[j])
        # Refining keeps a line's direction but extends its ends: its first point lies
        # nearer the coarse line's first point than its last one unless the line turned.
        d0 = float(np.hypot(*(first[i] - coarse[0])))
        d1 = float(np.hypot(*(first[i] - coarse[-1])))
        out[i] = law if d0 <= d1 else 1.0 - law
    return out


def combine(a: Measured, keep: np.ndarray, b: Measured | None = None) -> Measured:
    """Rows ``keep`` of ``a`` followed by all of ``b`` (if any)."""
    k = np.flatnonzero(keep)
    parts = [a] if b is None else [a, b]
    idx = [k] if b is None else [k, np.arange(len(b))]

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(x, name)[i] for x, i in zip(parts, idx, strict=True)])

    def lst(name: str) -> list[np.ndarray]:
        return [getattr(x, name)[j] for x, i in zip(parts, idx, strict=True) for j in i]

    arrays = ("own", "src", "end_a", "end_b", "time_mid", "plateau", "length_px", "width_px")
    flags = ("saturated", "crossing", "looped", "short")
    unmeasured = None
    if any(x.width_unmeasured is not None for x in parts):
        unmeasured = np.concatenate(
            [
                np.zeros(len(x), bool)[i] if x.width_unmeasured is None else x.width_unmeasured[i]
                for x, i in zip(parts, idx, strict=True)
            ]
        )
    return Measured(
        **{n: cat(n) for n in arrays + flags},
        points=lst("points"),
        profile=lst("profile"),
        sigma_c=a.sigma_c,
        sigma_raw=a.sigma_raw,
        width_unmeasured=unmeasured,
    )
