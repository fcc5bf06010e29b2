"""A frame's consensus start-to-end vector field: within one frame every dot draws nearly the
same curve (the camera's rotation moves every dot alike, up to perspective and the rolling
shutter), so the streaks' start-to-end vectors ``v`` at their time midpoints ``x`` follow an
affine field ``c0 + A x`` (a roll about the optical axis and perspective change the vector
linearly across the frame, to first order), fitted robustly and orientation-free
(:func:`consensus_field`). The streak table's quality (:mod:`blurtrack.detect.separation.quality`)
and separation (:mod:`blurtrack.detect.separation.separate`) measure each streak against it,
within :func:`shape_tolerance`. Pixels, frame coordinates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blurtrack.detect.params import QualityParams

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
    """``(N, 1)`` signs of the vectors ``v`` that make each voter agree with the signed voter
    it joins in a minimum spanning tree grown from the first voter; the other streaks agree
    with their nearest voter.

    An edge's cost is the squared distance of the time midpoints ``mid`` over what the pair
    says of the sign, ``|a . b| / max(|a|, |b|)`` (px: the shorter vector's length times the
    cosine between them): neighbours share the field, but a sub-pixel streak or a pair
    nearly at right angles carries no sign, and a tree through it flips every voter beyond
    it (a frame of short streaks that turn: the field's start lost half its voters)."""
    idx = np.flatnonzero(voters)
    sign = np.ones(len(v))
    vi = v[idx]
    length = np.hypot(*vi.T)
    says = np.abs(vi @ vi.T) / np.maximum(np.maximum(length[:, None], length[None]), 1e-9)
    cost = np.sum((mid[idx][:, None] - mid[idx][None]) ** 2, axis=2) / np.maximum(says, 1e-6)
    # Prim's algorithm: ``best`` the distance of each voter outside the tree to it (inf
    # inside), ``parent`` its nearest voter inside; the signs follow in the order grown.
    best = cost[0].copy()
    best[0] = np.inf
    parent = np.zeros(idx.size, np.int64)
    grown = np.zeros(max(idx.size - 1, 0), np.int64)
    # A voter's column of ``cost`` is set to inf as it joins, so that no row brings it back
    # (one strided write a step instead of two masked passes over ``best``).
    cost[:, 0] = np.inf
    for step in range(idx.size - 1):
        k = int(np.argmin(best))
        grown[step] = k
        cost[:, k] = np.inf
        best[k] = np.inf
        row = cost[k]
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
    P = np.linalg.pinv(Xu)  # the fit's coefficients are ``P @ vu``; the hat matrix ``Xu P``
    h = np.einsum("ij,ji->i", Xu, P)
    out = f.copy()
    out[use] = vu - (vu - Xu @ (P @ vu)) / np.maximum(1.0 - h, 1e-6)[:, None]
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
        return int(np.sum(voters & (nearest_sign(v, X @ coef)[1] <= tol)))

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
    c, dev = nearest_sign(v, f * sign)
    dev_held_out = nearest_sign(v, _held_out(X, f, v * sign, use) * sign)[1] if held_out else None
    return Consensus(c, dev, use, coef, centre, dev_held_out)


def nearest_sign(v: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c`` with each row's sign nearest to ``v``'s, and the distances ``|v - c|``."""
    dev_plus = np.hypot(*(v - c).T)
    dev_minus = np.hypot(*(v + c).T)
    return np.where((dev_minus < dev_plus)[:, None], -c, c), np.minimum(dev_plus, dev_minus)


def shape_tolerance(c: np.ndarray, q: QualityParams) -> np.ndarray:
    """``(N,)`` largest shape deviation that ``quality_ok`` accepts for consensus ``c``."""
    return np.maximum(q.shape_tol_px, q.shape_tol_rel * np.hypot(*c.T))
