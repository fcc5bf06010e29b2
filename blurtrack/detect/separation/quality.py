"""Per-streak quality: how far each streak's shape is from its frame's consensus, and one flag
that says whether a streak is fit for calibration.

Within one frame every dot draws nearly the same curve (the camera's rotation moves every dot
alike, up to perspective and the rolling shutter), so a streak whose start-to-end vector is far
from the frame's consensus is a merged chain, a fragment, a hook or noise.

- ``shape_deviation_px``: ``|v - c(x)|`` for the streak's start-to-end vector ``v`` and the
  frame's consensus ``c`` at its time midpoint ``x``: an affine field ``c0 + A x`` (a roll about
  the optical axis and perspective change the vector linearly across the frame, to first
  order) fitted robustly (three rounds, dropping residuals over 3 x their median) to the
  frame's unflagged streaks, each vector's sign chosen to agree with the dominant direction so
  that a wrong start/end does not count as a shape error (and, where a strong roll turns the
  vectors across the frame, from neighbour to neighbour and then against the fitted field,
  whichever field more streaks agree with); NaN when fewer than ``quality.min_reference``
  streaks can vote, or agree with the fitted field, each voter held out (below).
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
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from blurtrack.detect.params import DetectParams, QualityParams, SourceParams

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
#: Rounds of re-choosing each vector's sign against the fitted field (and refitting); a
#: budget: the rounds stop early where no sign changes.
RESIGN_ROUNDS = 3


@dataclass(frozen=True)
class Consensus:
    """A frame's consensus start-to-end vector field (see :func:`consensus_field`).

    ``c``: ``(N, 2)`` the consensus at each streak, with the sign nearest to its own vector;
    ``dev``: ``(N,)`` the distance ``|v - c|``; ``use``: the voters the robust fit kept;
    ``dev_held_out``: ``(N,)`` each kept voter's distance from the field fitted to the others
    (the others' ``dev``; :func:`_held_out`), where asked for."""

    c: np.ndarray
    dev: np.ndarray
    use: np.ndarray
    coef: np.ndarray
    centre: np.ndarray
    dev_held_out: np.ndarray | None = None

    def at(self, xy: np.ndarray) -> np.ndarray:
        """``(M, 2)`` consensus vectors at points ``xy`` (the dominant direction's sign)."""
        X = np.column_stack([np.ones(len(xy)), (xy - self.centre) / 100.0])
        return np.asarray(X @ self.coef)


def _robust_affine(
    X: np.ndarray, vs: np.ndarray, voters: np.ndarray, start: np.ndarray, min_reference: int
) -> tuple[np.ndarray, np.ndarray]:
    """Affine field from ``start``, refitted over rounds that keep the ``voters`` within 3x
    the median residual; returns the coefficients and the voters of the last round."""
    use = start.copy()
    for _ in range(5):
        coef = np.linalg.lstsq(X[use], vs[use], rcond=None)[0]
        r = np.hypot(*(vs - X @ coef).T)
        cut = max(3.0 * float(np.median(r[use])), 0.5)
        new = voters & (r <= cut)
        if int(new.sum()) < min_reference:
            break
        if np.array_equal(new, use):
            break  # a fixed point: further rounds refit the very same voters
        use = new
    return coef, use


def _propagated_signs(v: np.ndarray, mid: np.ndarray, voters: np.ndarray) -> np.ndarray:
    """``(N, 1)`` signs of the vectors ``v`` that make each voter agree with its nearest
    signed voter (a minimum spanning tree over the time midpoints ``mid``, grown from the
    first voter); the other streaks agree with their nearest voter."""
    idx = np.flatnonzero(voters)
    sign = np.ones(len(v))
    d2 = np.sum((mid[idx][:, None] - mid[idx][None]) ** 2, axis=2)
    # Prim's algorithm: ``best`` the distance of each voter outside the tree to it (inf
    # inside), ``parent`` its nearest voter inside; the signs follow in the order grown.
    best = d2[0].copy()
    best[0] = np.inf
    parent = np.zeros(idx.size, np.int64)
    grown = np.zeros(max(idx.size - 1, 0), np.int64)
    # A voter's column of ``d2`` is set to inf as it joins, so that no row brings it back
    # (one strided write a step instead of two masked passes over ``best``).
    d2[:, 0] = np.inf
    for step in range(idx.size - 1):
        k = int(np.argmin(best))
        grown[step] = k
        d2[:, k] = np.inf
        best[k] = np.inf
        row = d2[k]
        parent[row < best] = k
        np.minimum(best, row, out=best)
    a, b = v[idx[grown]], v[idx[parent[grown]]]
    flips = (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] < 0).tolist()
    voter_sign = [1.0] * idx.size
    for k, j, f in zip(grown.tolist(), parent[grown].tolist(), flips, strict=True):
        voter_sign[k] = -voter_sign[j] if f else voter_sign[j]
    sign[idx] = voter_sign
    rest = np.flatnonzero(~voters)
    if rest.size:
        j = idx[np.argmin(np.sum((mid[rest][:, None] - mid[idx][None]) ** 2, axis=2), axis=1)]
        sign[rest] = np.where(np.sum(v[rest] * v[j], axis=1) < 0, -sign[j], sign[j])
    return sign[:, None]


def _held_out(X: np.ndarray, f: np.ndarray, vs: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The field ``f (N, 2)`` with each voter of ``use`` given the value that the least-squares
    fit over the other voters of ``use`` predicts there (the others' values as they are):
    ``vs - e / (1 - h)``, ``e`` its residual from the fit over all of ``use`` and ``h`` its
    leverage (the hat matrix's diagonal; the field's three coefficients per axis spread over
    the voters, ``sum(h) = 3``). A voter that alone decides the field there (``h`` near 1)
    gets a value far from its own."""
    Xu, vu = X[use], vs[use]
    beta = np.linalg.lstsq(Xu, vu, rcond=None)[0]
    h = np.einsum("ij,jk,ik->i", Xu, np.linalg.pinv(Xu.T @ Xu), Xu)
    out = f.copy()
    out[use] = vu - (vu - Xu @ beta) / np.maximum(1.0 - h, 1e-6)[:, None]
    return out


def consensus_field(
    v: np.ndarray,
    mid: np.ndarray,
    voters: np.ndarray,
    q: QualityParams,
    resign: bool = False,
    held_out: bool = False,
) -> Consensus | None:
    """The frame's consensus start-to-end vector at every streak, orientation-free.

    Args:
        v: ``(N, 2)`` start-to-end (or A-to-B) vectors.
        mid: ``(N, 2)`` time midpoints.
        voters: ``(N,)`` bool, the streaks that may vote.
        q: the fewest voters and the shape tolerance.
        resign: also start from signs propagated between neighbours and re-choose each
            vector's sign against the fitted field (:data:`RESIGN_ROUNDS`): a strong roll
            turns the vectors across the frame, so one axis's sign splits the field. The
            quality flags use it; separation keeps the dominant axis's signs.
        held_out: also each kept voter's deviation from the field fitted to the others
            (``dev_held_out``; :func:`_held_out`), not from one it pulled towards itself:
            with few voters the affine field's six coefficients bend to each of them, and a
            few lines on a facade's lit bars agree with a field they made (with hundreds of
            voters the two differ by about a percent). The quality flags count the voters
            that agree with it.
    Returns:
        The field, or None when fewer than ``q.min_reference`` streaks vote.
    """
    if int(voters.sum()) < q.min_reference:
        return None
    ref = v[voters]
    # Dominant direction from the second-moment matrix (orientation-free), then signs.
    _, vecs = np.linalg.eigh(ref.T @ ref)
    axis = vecs[:, -1]
    sign = np.where(v @ axis < 0, -1.0, 1.0)[:, None]
    vs = v * sign
    centre = mid[voters].mean(axis=0)
    X = np.column_stack([np.ones(len(v)), (mid - centre) / 100.0])
    # Two starts: all voters, and those near the median vector (chains of several streaks
    # can pull a least-squares start so far that no residual cut removes them); each round
    # refits and re-admits the voters within 3x the median residual, so the field grows over
    # the frame. The start whose field more voters agree with (within the tolerance) wins.
    med = np.median(vs[voters], axis=0)
    near = np.hypot(*(vs - med).T) <= 2.0 * max(q.shape_tol_px, q.shape_tol_rel * np.hypot(*med))
    tol = np.maximum(q.shape_tol_px, q.shape_tol_rel * np.hypot(*v.T))

    def agreeing(coef: np.ndarray) -> int:  # orientation-free
        c = X @ coef
        dev = np.minimum(np.hypot(*(v - c).T), np.hypot(*(v + c).T))
        return int(np.sum(voters & (dev <= tol)))

    starts: list[Callable[[], tuple[np.ndarray, np.ndarray]]] = [lambda: (sign, voters)]
    close = voters & near
    # (A start equal to the first would fit the very same field.)
    if int(close.sum()) >= q.min_reference and not np.array_equal(close, voters):
        starts.append(lambda: (sign, close))
    # A strong roll turns the vectors across the frame, so one axis's sign splits the field:
    # (resign) a third start takes each voter's sign from its nearest signed neighbour.
    if resign:
        starts.append(lambda: (_propagated_signs(v, mid, voters), voters))
    n_voters = int(voters.sum())
    best: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
    for make_start in starts:
        if best is not None and best[0] == n_voters:
            break  # every voter agrees: no later start can win (it must do strictly better)
        sg, start = make_start()
        coef, use = _robust_affine(X, v * sg, voters, start, q.min_reference)
        for _ in range(RESIGN_ROUNDS if resign else 0):  # signs re-chosen against the field
            new_sg = np.where(np.sum(v * (X @ coef), axis=1) < 0, -1.0, 1.0)[:, None]
            if np.array_equal(new_sg, sg):
                break
            sg = new_sg
            coef, use = _robust_affine(X, v * sg, voters, use, q.min_reference)
        score = agreeing(coef)
        if best is None or score > best[0]:
            best = (score, coef, use, sg)
    assert best is not None
    _, coef, use, sign = best
    f = X @ coef
    c, dev = _nearest_sign(v, f * sign)
    dev_held_out = _nearest_sign(v, _held_out(X, f, v * sign, use) * sign)[1] if held_out else None
    return Consensus(c, dev, use, coef, centre, dev_held_out)


def _nearest_sign(v: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c`` with each row's sign nearest to ``v``'s, and the distances ``|v - c|``."""
    dev_plus = np.hypot(*(v - c).T)
    dev_minus = np.hypot(*(v + c).T)
    return np.where((dev_minus < dev_plus)[:, None], -c, c), np.minimum(dev_plus, dev_minus)


def shape_tolerance(c: np.ndarray, q: QualityParams) -> np.ndarray:
    """``(N,)`` largest shape deviation that ``quality_ok`` accepts for consensus ``c``."""
    return np.maximum(q.shape_tol_px, q.shape_tol_rel * np.hypot(*c.T))


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
    :func:`blurtrack.detect.gyro.gyrotrust.apply_check`) can lift one doubt, never two: two
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
