"""Per-streak quality: how far each streak's shape is from its frame's consensus, and one flag
that says whether a streak is fit for calibration.

Within one frame every dot draws nearly the same curve (the camera's rotation moves every dot
alike, up to perspective and the rolling shutter), so a streak whose start-to-end vector is far
from the frame's consensus is a merged chain, a fragment, a hook or noise.

- ``shape_deviation_px``: ``|v - c(x)|`` for the streak's start-to-end vector ``v`` and the
  frame's consensus ``c`` at its time midpoint ``x``
  (:func:`blurtrack.detect.separation.consensus.consensus_field`): an affine field
  ``c0 + A x`` (a roll about the optical axis and perspective change the vector linearly
  across the frame, to first order) fitted robustly (three rounds, dropping residuals over
  3 x their median) to the frame's unflagged streaks, each vector's sign chosen to agree
  with the dominant direction so that a wrong start/end does not count as a shape error
  (and, where a strong roll turns the vectors across the frame, from neighbour to neighbour
  and then against the fitted field, whichever field more streaks agree with); NaN when
  fewer than ``quality.min_reference`` streaks can vote, or agree with the fitted field,
  each voter held out (below).
- ``thick_saturated``: saturated and wider than ``quality.thick_width_ratio`` x the frame's
  dot width (the median of its unsaturated streaks', or of all where fewer than
  ``quality.min_reference`` are unsaturated): a blown-out core whose centre line and ends are
  unreliable. A streak without a measured width (NaN: a hairpin of two blown-out arms, whose
  arms the gyro pass measured apart) is not thick, and the widths that are NaN do not count
  in the frame's dot width.
- ``source``: ``point``, ``extended`` or ``undetermined``, from the frame's image
  (:mod:`blurtrack.detect.trust`); a table without that evidence is ``undetermined``.
- ``quality_ok``: one whole point-light streak with trustworthy ends: ``source`` is
  ``point``, none of ``clipped``, ``merged``, ``crossing``, ``looped``, ``thick_saturated``,
  no neighbour's light just beyond an end, and a shape within
  ``max(shape_tol_px, shape_tol_rel |c|)`` of the consensus. A frame without a consensus
  (fewer than ``quality.min_reference`` clean point lights, or fewer than that many of them
  within the tolerance of the field fitted to the others, each held out: the robust fit
  always returns a field, which only the streaks that agree with it make a consensus, and
  with few voters an affine field bends to each of them) has no ``quality_ok`` streak: no
  other streak says that a line is a dot's blur rather than a highlight, a ridge of texture
  or a sign's letter (``ends_unsure``; the gyro, which predicts the shape, may confirm it).
  A saturated core alone does not disqualify: its ends are measured on the unclipped profile.
- ``reason``: why (the first that applies, in the order of :data:`REASONS`), ``ok`` when
  ``quality_ok``.

Thresholds: :class:`~blurtrack.detect.paramsections.QualityParams` (``quality`` of
:class:`~blurtrack.detect.params.DetectParams`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from blurtrack.detect.params import DetectParams, QualityParams, SourceParams
from blurtrack.detect.separation.consensus import consensus_field, shape_tolerance

if TYPE_CHECKING:  # the table's type only: detection itself does not need pandas
    import pandas as pd

    from blurtrack.detect.frame import FrameStreaks

#: Flags that keep a streak out of the shape consensus (and out of ``quality_ok``).
FLAGGED_BY = ("clipped", "merged", "crossing", "looped")
#: The closed set of ``reason`` values, in the order they are tested (the first that applies):
#:
#: - ``ok``: ``quality_ok``;
#: - ``clipped``: an end at the border (the dot entered or left the frame), or too near it
#:   for the light beyond the end to be measured;
#: - ``extended``: the light of an extended source (a lit window, sign, glare), not a point;
#: - ``crossing``: crosses another streak; ``looped``: crosses itself;
#: - ``touching``: wider than the frame's dot (a neighbour alongside: ``merged``);
#: - ``chained``: a neighbour's light continues it beyond an end, or it is far longer than
#:   the frame's consensus streak (two dots' streaks end to end);
#: - ``fragment``: far shorter than the consensus (a part of a streak);
#: - ``hairpin``: (with a gyro) the predicted path doubles back beyond its start or end, so
#:   the visible ends are turns, not the ends (:mod:`blurtrack.detect.gyro.gyrotrust`);
#: - ``gyro_mismatch``: (with a gyro) the start-to-end vector is off the gyro's prediction;
#: - ``ends_unsure``: a blown-out core wider than the dot (``thick_saturated``), a shape that
#:   is neither (a hook, a wrong end), or a source that is neither point nor extended.
REASONS = (
    "ok",
    "clipped",
    "extended",
    "crossing",
    "looped",
    "touching",
    "chained",
    "fragment",
    "hairpin",
    "gyro_mismatch",
    "ends_unsure",
)

#: Columns :func:`add_quality` adds, in order (``frame_quality`` returns them in this order).
QUALITY_COLUMNS = ("shape_deviation_px", "thick_saturated", "quality_ok", "source", "reason")


def _frame_quality(
    v: np.ndarray,
    mid: np.ndarray,
    flags: dict[str, np.ndarray],
    width: np.ndarray,
    source: np.ndarray,
    end_light: np.ndarray,
    p: SourceParams,
    q: QualityParams,
    short: np.ndarray | None = None,
) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """The :data:`QUALITY_COLUMNS` of one frame's streaks from their start-to-end vectors,
    time midpoints, flags (``clipped``, ``saturated``, ``merged``, ``crossing``,
    ``looped``), widths, sources and end light, and ``(N,)`` which streaks not
    ``quality_ok`` have one doubt the gyro may lift (:func:`one_doubt`). ``short``: ``(N,)`` the
    streaks whose ends came from the profile's moments, not an edge fit each
    (:class:`~blurtrack.detect.lines.endpoints.EdgeFit`); None: all of them."""
    sat = flags["saturated"]
    # The dot's width from the unsaturated streaks, where enough of them say it (a frame of
    # saturated streaks but one or two faint ones would call every streak thick): else from
    # all (a saturated width is measured on the clipped cross-section's flanks).
    ref_w = width[~sat & np.isfinite(width)]
    ref_w = ref_w if ref_w.size >= q.min_reference else width[np.isfinite(width)]
    w0 = float(np.median(ref_w)) if ref_w.size else np.nan
    with np.errstate(invalid="ignore"):
        thick = sat & (width > q.thick_width_ratio * w0)
    flagged = np.logical_or.reduce([flags[c] for c in FLAGGED_BY])
    point = source == "point"
    with np.errstate(invalid="ignore"):  # NaN (an end too near the border): not lit
        lit = end_light > p.end_light_max
    lit_end = lit.any(axis=1)
    at_border = flags["clipped"] | np.any(np.isnan(end_light), axis=1)
    dev = np.full(len(v), np.nan)
    ok = point & ~(flagged | thick | lit_end | at_border)
    long_ = short_ = bent = np.zeros(len(v), bool)
    # The consensus from point lights only: an extended source's lines say nothing of the
    # dots' curve. Without one (fewer than ``q.min_reference`` clean point lights, voting or
    # agreeing) no other streak of the frame says that a streak is a dot's blur, not a
    # highlight, an edge or a letter.
    voters = point & ~(flagged | thick)
    field = consensus_field(v, mid, voters, q, resign=True, held_out=True)
    if field is not None:
        tol = shape_tolerance(field.c, q)
        # Each held out: a voter agrees with what the others' field predicts for it.
        assert field.dev_held_out is not None
        if int(np.sum(voters & (field.dev_held_out <= tol))) < q.min_reference:
            field = None  # fitted, but too few clean point lights agree with it: no consensus
    unchecked = np.full(len(v), field is None)
    ok &= ~unchecked
    if field is not None:
        dev = field.dev
        bent = dev > tol
        c_len = np.hypot(*field.c.T)
        length = np.hypot(*v.T)
        long_ = bent & (length > c_len + tol)
        short_ = bent & (length < c_len - tol)
        ok &= ~bent
    # A neighbour's light beyond an end moves that end's edge fit only, but the moments of a
    # short streak's whole profile: both its ends (a doubt against each).
    moments = np.ones(len(v), bool) if short is None else np.asarray(short, bool)
    single = ~ok & one_doubt(
        point & ~(at_border | flags["looped"] | flags["merged"] | short_),
        [*lit.T, *(lit & moments[:, None]).T, thick, bent, unchecked],
        flags["crossing"],
    )
    reason = np.full(len(v), "ends_unsure", object)
    # Assigned from the last to the first, so that the first that applies stays.
    reason[short_] = "fragment"
    reason[lit_end | long_] = "chained"
    reason[flags["merged"] & ~flags["crossing"]] = "touching"
    reason[flags["looped"]] = "looped"
    reason[flags["crossing"]] = "crossing"
    reason[source == "extended"] = "extended"
    reason[at_border] = "clipped"
    reason[ok] = "ok"
    return (dev, thick, ok, source.astype(object), reason), single


def one_doubt(eligible: np.ndarray, doubts: list[np.ndarray], crossing: np.ndarray) -> np.ndarray:
    """``(N,)`` the ``eligible`` streaks (a point light away from the border, neither looped,
    touching nor a fragment) against which exactly one of the ``doubts`` (``(N,)`` bools: a
    lit end (each end one doubt; two where the ends came from the moments of the whole
    profile), a blown-out core, a shape off the frame's consensus or no consensus at all)
    speaks, or none of them and a ``crossing``. The image alone cannot tell whether such a
    streak's ends are right; an independent measure of its start-to-end vector (the gyro's,
    :func:`blurtrack.detect.gyro.framecheck.apply_check`) can lift one doubt, never two: two
    doubted ends may be moved alike (a neighbour alongside, ends from the profile's
    moments), which the vector does not see. A crossing does not count against that one: the
    other streak's light runs across this one, not along it (measured on ``hard`` seeds 1-8:
    of the crossing streaks with one more doubt whose vector fits, 429 of 433 have both ends
    within 2 px, the four others 2.1-2.4 px)."""
    count = np.sum([np.asarray(d, bool) for d in doubts], axis=0)
    cross = np.asarray(crossing, bool)
    return np.asarray(eligible & ((count == 1) | ((count == 0) & cross)))


def _flags(get: Callable[[str], np.ndarray]) -> dict[str, np.ndarray]:
    return {c: get(c) for c in (*FLAGGED_BY, "saturated")}


def frame_quality(
    fs: FrameStreaks, p: DetectParams | None = None
) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """:func:`add_quality`'s columns for one frame's streaks, and which of them have exactly
    one doubt (:func:`one_doubt`), from the frame itself
    (the frame's worker computes them: frames are independent; ``p``: its ``source`` and
    ``quality`` sections, defaults if None). They do not depend on which
    end is A: the consensus takes each vector's sign from the dominant direction and the
    deviation is the nearer of ``|v - c|`` and ``|v + c|``, so the table's values after
    orientation are these."""
    n = len(fs)
    ev = fs.evidence
    source = ev.source if ev is not None else np.full(n, "undetermined", object)
    light = ev.end_light if ev is not None else np.zeros((n, 2))
    flags = _flags(lambda c: fs.flags[c])
    p = p or DetectParams()
    v = fs.end_b - fs.end_a
    short = fs.short if len(fs.short) == n else None
    return _frame_quality(
        v, fs.time_mid, flags, fs.width_px, source, light, p.source, p.quality, short
    )


def add_quality(table: pd.DataFrame, p: DetectParams | None = None) -> pd.DataFrame:
    """``table`` with the :data:`QUALITY_COLUMNS` (``p``: the ``source`` and ``quality``
    sections, defaults if None). The image evidence comes from the
    table's ``source``, ``end_light_start`` and ``end_light_end`` columns; without a
    ``source`` column every streak is ``undetermined`` (and none ``quality_ok``). The
    ``merged`` column there is ``merged`` or ``crossing`` (the table's definition)."""
    out = table.copy()
    n = len(out)
    p = p or DetectParams()
    cols: list[np.ndarray] = [
        np.full(n, np.nan),
        np.zeros(n, bool),
        np.zeros(n, bool),
        np.full(n, "undetermined", object),
        np.full(n, "ends_unsure", object),
    ]
    if n:
        # The columns as arrays once; the frames are then slices of them (no per-frame
        # DataFrame indexing, which cost more than the fits).
        v = out[["end_x", "end_y"]].to_numpy(float) - out[["start_x", "start_y"]].to_numpy(float)
        mid = out[["mid_x", "mid_y"]].to_numpy(float)
        flags = _flags(lambda c: out[c].to_numpy(bool))
        width = out["width_px"].to_numpy(float)
        source = (
            out["source"].to_numpy(object)
            if "source" in out.columns
            else np.full(n, "undetermined", object)
        )
        light = np.zeros((n, 2))
        for j, c in enumerate(("end_light_start", "end_light_end")):
            if c in out.columns:
                light[:, j] = out[c].to_numpy(float)
        frames = out["frame"].to_numpy()
        order = np.argsort(frames, kind="stable")
        bounds = np.flatnonzero(np.diff(frames[order])) + 1
        for rows in np.split(order, bounds):
            res = _frame_quality(
                v[rows],
                mid[rows],
                {k: f[rows] for k, f in flags.items()},
                width[rows],
                source[rows],
                light[rows],
                p.source,
                p.quality,
            )
            for col, r in zip(cols, res[0], strict=True):
                col[rows] = r
    for name, col in zip(QUALITY_COLUMNS, cols, strict=True):
        out[name] = col
    return out
