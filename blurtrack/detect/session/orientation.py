"""Which end of a streak is the start of exposure.

A single image cannot tell: the streak of a motion and of its reverse are the same picture.
Three cues, each a log-likelihood ratio (LLR, natural log) in favour of "end A is the start"
(positive) against "end B is the start", are summed:

- ``gyro``: the blur model with the session's initial calibration predicts, from the streak's
  time midpoint (the point that halves its light, i.e. its mid-exposure position), where the
  dot was at the start and at the end of its row's exposure. The pairing of detected ends with
  predicted ones that fits better wins; the prediction's uncertainty grows with the streak's
  length, since the initial guesses (time shift, intrinsics, R_cam_imu) may be off.
- ``profile``: brightness is inversely proportional to speed. The gyro predicts the dot's speed
  at the start and at the end; the plateau brightness ratio of the two ends must match.
- ``continuity``: in the gap between exposures the dot keeps moving. Extrapolating each end
  outwards along its tangent, at the speed its brightness implies, over the gap, the previous
  frame must have an end near the extrapolated start and the next frame one near the
  extrapolated end. Other dots' ends lie about too (clutter), so an end found near an
  extrapolated point is evidence only in proportion to how unlikely a stranger's is there
  (:func:`continuity_llr`).

``confidence = sigmoid(|LLR|)`` in [0.5, 1); ``source`` names the cue that contributed most to
the decision (``none`` when no cue had evidence).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from blurtrack.detect.forkmap import batch_positions
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.paramsections import OrientationParams

CUE_NAMES = ("gyro", "profile", "continuity")
#: Rotation-integration sub-step of the models behind the gyro cue and the time-shift scan
#: (the model's default is 1 ms): they compare ends against a tolerance of >= 1.5 px, and a
#: 4 ms midpoint rule moves the predicted ends by < 0.01 px on ``dense`` and ``hard``.
CUE_SUBSTEP_S = 4e-3


@dataclass(frozen=True)
class CueErrors:
    """The cues' error model for one session (:class:`~blurtrack.detect.params.OrientationParams`,
    :func:`cue_errors`): the gyro's predicted ends scatter by ``sigma_px + sigma_rel *
    length`` (px), log brightness ratios by ``profile_sigma_log``; a dot's own end lies near
    its extrapolated one in a neighbouring frame with probability ``continuity_present``,
    among other ends counted within ``continuity_radius`` extrapolation uncertainties
    (:func:`continuity_llr`); every LLR is clipped to ``+-max_llr``."""

    sigma_px: float = OrientationParams().gyro_sigma_px
    sigma_rel: float = OrientationParams().gyro_sigma_rel
    profile_sigma_log: float = OrientationParams().profile_sigma_log
    max_llr: float = OrientationParams().max_cue_llr
    continuity_present: float = OrientationParams().continuity_present
    continuity_radius: float = OrientationParams().continuity_radius


def cue_errors(p: OrientationParams, refined: bool) -> CueErrors:
    """The error model of ``p``, with the smaller relative part where the time-shift scan
    found the shift (``refined``; the continuity cue does not depend on it)."""
    rel = p.gyro_sigma_rel_refined if refined else p.gyro_sigma_rel
    return CueErrors(
        p.gyro_sigma_px,
        rel,
        p.profile_sigma_log,
        p.max_cue_llr,
        p.continuity_present,
        p.continuity_radius,
    )


@dataclass(frozen=True)
class FrameTiming:
    """Timing of one frame on the camera clock (seconds)."""

    t_s: float
    exposure_s: float


@dataclass(frozen=True)
class Orientation:
    """Per streak of a frame: ``swap`` (end B is the start), ``confidence``, ``source``, and
    the per-cue LLRs ``(N, 3)`` in :data:`CUE_NAMES` order (positive: A is the start)."""

    swap: np.ndarray
    confidence: np.ndarray
    source: list[str]
    llr: np.ndarray


def gyro_cues(
    fs: FrameStreaks, timing: FrameTiming, model: object, errors: CueErrors | None = None
) -> np.ndarray:
    """``(N, 2)`` LLRs of the gyro and profile cues for one frame.

    ``model`` is a :class:`blurtrack.geometry.blur_model.BlurModel` (camera clock); it must cover
    the frame's exposure (:class:`~blurtrack.errors.CoverageError` otherwise). ``errors``: the
    cues' error model (defaults if None; a smaller relative part once the time shift has been
    refined).
    """
    return gyro_cues_batch([fs], [timing], model, errors)[0]


#: Streaks per batched model call of :func:`gyro_cues_batch` (bounds the temporaries).
GYRO_BATCH_STREAKS = 20000


def gyro_cues_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: object,
    errors: CueErrors | None = None,
) -> list[np.ndarray]:
    """:func:`gyro_cues` of many frames with one model evaluation per batch of streaks.

    The model's per-call cost is mostly fixed (its rotation integration loops over sub-steps
    in Python), so the streaks of many frames go through it together, at most
    :data:`GYRO_BATCH_STREAKS` at a time. Every frame must be covered by the gyro.
    """
    out = [np.zeros((len(fs), 2)) for fs in frames]
    for g in gyro_cue_batches(frames):
        for j, part in zip(g, gyro_cues_of_batch(frames, timings, g, model, errors), strict=True):
            out[j] = part
    return out


def gyro_cue_batches(frames: Sequence[FrameStreaks]) -> list[list[int]]:
    """The positions in ``frames`` of :func:`gyro_cues_batch`'s model calls, in order (the
    frames with streaks, at most :data:`GYRO_BATCH_STREAKS` streaks a batch)."""
    return batch_positions(
        ((k, len(fs)) for k, fs in enumerate(frames) if len(fs)), GYRO_BATCH_STREAKS
    )


def gyro_cues_of_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    batch: Sequence[int],
    model: object,
    errors: CueErrors | None = None,
) -> list[np.ndarray]:
    """The ``(N, 2)`` cues of the frames at the positions ``batch`` (one of
    :func:`gyro_cue_batches`), in one model call: batch by batch, :func:`gyro_cues_batch`'s very
    numbers (so that the batches may be computed in several processes)."""
    llr = _gyro_cues_flat(
        [frames[j] for j in batch], [timings[j] for j in batch], model, errors or CueErrors()
    )
    return np.split(llr, np.cumsum([len(frames[j]) for j in batch])[:-1])


def _gyro_cues_flat(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: object,
    errors: CueErrors,
) -> np.ndarray:
    """The gyro and profile LLRs ``(sum N, 2)`` of the streaks of ``frames``, concatenated."""
    cam = model.camera  # type: ignore[attr-defined]
    counts = [len(fs) for fs in frames]
    mid = np.concatenate([fs.time_mid for fs in frames])
    ft = np.repeat([tm.t_s for tm in timings], counts)
    exp = np.repeat([tm.exposure_s for tm in timings], counts)
    A = np.concatenate([fs.end_a for fs in frames])
    B = np.concatenate([fs.end_b for fs in frames])
    length = np.concatenate([fs.length_px for fs in frames])
    plateau = np.concatenate([fs.plateau for fs in frames])
    short = np.concatenate(
        [fs.short if len(fs.short) == len(fs) else np.zeros(len(fs), bool) for fs in frames]
    )
    row_t = ft + cam.readout_s * np.clip(mid[:, 1], 0, cam.height - 1) / cam.height
    t_ref = row_t + 0.5 * exp
    start, end, t_s, t_e = model.streak_endpoints(mid, t_ref, ft, exp)  # type: ignore[attr-defined]
    out = np.zeros((mid.shape[0], 2))
    cost_a = np.sum((A - start) ** 2, axis=1) + np.sum((B - end) ** 2, axis=1)
    cost_b = np.sum((B - start) ** 2, axis=1) + np.sum((A - end) ** 2, axis=1)
    sig = errors.sigma_px + errors.sigma_rel * length
    out[:, 0] = (cost_b - cost_a) / (2 * sig**2)
    # Profile: predicted speeds at both ends vs the ends' plateau brightness (one warp call
    # for both ends).
    dt = np.maximum(exp / 20.0, 1e-5)
    n = mid.shape[0]
    moved = model.warp(  # type: ignore[attr-defined]
        np.concatenate([start, end]),
        np.concatenate([t_s, t_e]),
        np.concatenate([t_s + dt, t_e - dt]),
    )
    v_s = np.hypot(*(moved[:n] - start).T)
    v_e = np.hypot(*(moved[n:] - end).T)
    usable = (~short) & np.all(plateau > 0, axis=1) & (v_s > 0) & (v_e > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(plateau[:, 0] / plateau[:, 1])
        q = np.log(v_e / v_s)  # expected r if A is the start
    llr = ((r + q) ** 2 - (r - q) ** 2) / (2 * errors.profile_sigma_log**2)
    out[:, 1] = np.where(usable & np.isfinite(llr), llr, 0.0)
    return np.clip(out, -errors.max_llr, errors.max_llr)


def _outward_tangents(points: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit tangents ``(N, 2)`` at end A and end B of each centre line, from the last
    ~3 px (all lines at once: one flat gather)."""
    n = np.array([len(p) for p in points], dtype=np.int64)
    if n.size == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    flat = np.concatenate(points).reshape(-1, 2)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    last = first + n - 1
    k = np.minimum(3, n - 1)
    da = flat[first] - flat[first + k]
    db = flat[last] - flat[last - k]
    na = np.maximum(np.hypot(da[:, 0], da[:, 1]), 1e-9)[:, None]
    nb = np.maximum(np.hypot(db[:, 0], db[:, 1]), 1e-9)[:, None]
    return da / na, db / nb


def _extrapolation_basis(
    fs: FrameStreaks, timing: FrameTiming
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outward tangents at ends A and B and the speed (px/s) at each end, ``(N, 2)`` each:
    the part of :func:`_extrapolated_ends` that does not depend on the gap."""
    out_a, out_b = _outward_tangents(fs.points)
    mean_speed = fs.length_px / max(timing.exposure_s, 1e-6)  # px/s
    sizes = np.array([p.size for p in fs.profile], dtype=np.int64)
    level = np.zeros(len(fs))
    if sizes.size:
        # A trailing 0 keeps every segment start inside the array; empty profiles give 0.
        flat = np.concatenate([*fs.profile, np.zeros(1)])
        sums = np.add.reduceat(flat, np.concatenate([[0], np.cumsum(sizes)[:-1]]))
        level = np.where(sizes > 0, sums / np.maximum(sizes, 1), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(fs.plateau > 0, level[:, None] / fs.plateau, 1.0)
    ratio = np.clip(np.nan_to_num(ratio, nan=1.0), 0.2, 5.0)
    return out_a, out_b, mean_speed[:, None] * ratio


def _extrapolated_ends(
    fs: FrameStreaks,
    timing: FrameTiming,
    gap_s: float,
    basis: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ends A and B pushed outwards over ``gap_s`` at the speed their brightness implies, and
    the per-streak uncertainty (px) of that extrapolation (``basis``: the frame's
    :func:`_extrapolation_basis`, if already known)."""
    out_a, out_b, speed = _extrapolation_basis(fs, timing) if basis is None else basis
    step = speed * gap_s  # (N, 2) px travelled in the gap
    ext_a = fs.end_a + out_a * step[:, 0:1]
    ext_b = fs.end_b + out_b * step[:, 1:2]
    unc = 2.0 + 0.5 * np.max(step, axis=1)
    return ext_a, ext_b, unc


#: Query rows per block of :func:`nearest_and_count` (bounds its distance matrix).
NEAREST_BLOCK = 512


def nearest_and_count(
    queries: np.ndarray, points: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``queries (N, 2)``: the distance ``(N,)`` to the nearest of ``points (M,
    2)`` and how many of them lie within its ``radius (N,)`` (px), exhaustively, in blocks of
    :data:`NEAREST_BLOCK` queries."""
    out = np.empty(queries.shape[0])
    count = np.zeros(queries.shape[0], np.int64)
    p2 = np.einsum("ij,ij->i", points, points)
    for a in range(0, queries.shape[0], NEAREST_BLOCK):
        q = queries[a : a + NEAREST_BLOCK]
        q2 = np.einsum("ij,ij->i", q, q)
        # |q - p|^2 = |q|^2 + |p|^2 - 2 q.p: one matrix product instead of two broadcasts,
        # |q|^2 added per row after the reductions (one temporary, updated in place).
        g = q @ points.T
        g *= -2.0
        g += p2
        out[a : a + NEAREST_BLOCK] = np.sqrt(np.maximum(np.min(g, axis=1) + q2, 0.0))
        r = radius[a : a + NEAREST_BLOCK]
        count[a : a + NEAREST_BLOCK] = np.count_nonzero(g <= (r * r - q2)[:, None], axis=1)
    return out, count


def continuity_llr(
    d_px: np.ndarray, unc_px: np.ndarray, density_px2: np.ndarray, present: float
) -> np.ndarray:
    """``(N,)`` log of how much likelier the nearest neighbouring end at ``d_px`` is where the
    dot's own end is expected (its extrapolation's uncertainty ``unc_px``) than where only
    other dots' ends are (``density_px2``: ends per px^2 about the point).

    Other ends are a Poisson field of density ``lam`` (``density_px2``, > 0), whose nearest
    lies at ``d`` with density ``2 pi lam d exp(-pi lam d^2)``; the dot's own end is there
    with probability ``q`` (``present``: found in the neighbouring frame, and the motion
    through the gap as extrapolated), scattered as a 2-D Gaussian of ``unc`` about the point.
    The nearest end's likelihood ratio of the two is ``1 - q + q exp(-d^2 / 2 unc^2) (1 + 1 /
    (2 pi lam unc^2))``: at most ``ln(1 + q / (2 pi lam unc^2))`` where ends crowd (a
    stranger's end is as likely there), at least ``ln(1 - q)`` far from any end (the dot's
    own may be missing)."""
    q = float(present)
    crowd = 1.0 + 1.0 / (2.0 * np.pi * density_px2 * unc_px**2)
    ratio = 1.0 - q + q * np.exp(-(d_px**2) / (2.0 * unc_px**2)) * crowd
    return np.asarray(np.log(ratio))


def continuity_cues(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    swaps: Sequence[np.ndarray | None] | None = None,
    cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    errors: CueErrors = CueErrors(),
    only: range | None = None,
) -> list[np.ndarray]:
    """Per frame, ``(N,)`` LLRs of the continuity cue (0 where no neighbour has evidence),
    clipped to ``+-errors.max_llr`` (:class:`CueErrors`).

    Each neighbouring frame adds :func:`continuity_llr` at the extrapolated start less that
    at the extrapolated end (the next frame: the other way round), the density of ends about
    each point counted within ``errors.continuity_radius`` uncertainties of it, the nearest
    (the dot's own, where it is there) not counted, and at least one.

    Without ``swaps`` any end of a neighbouring frame may continue a streak. With ``swaps``
    (a tentative orientation per frame, True where end B is the start; None for a frame whose
    neighbours are not computed, ``only``) only the
    previous frame's ends and the next frame's starts count, which removes the ambiguity of
    a dot that reverses in the gap between exposures. ``cache``: per frame index, its
    :func:`_extrapolation_basis` (filled here; pass the same dict to calls on the same,
    unchanged frames to compute it once). ``only``: the frames to compute (the others' LLRs
    stay 0; with ``swaps``, only those of the frames next to them are read), so that the
    frames may be computed in parts: each frame's LLRs are the same as computed with all.
    """
    out = [np.zeros(len(fs)) for fs in frames]
    bases = {} if cache is None else cache

    def tree(k: int, want: str) -> np.ndarray | None:
        fs = frames[k]
        if len(fs) == 0:
            return None
        if swaps is None:
            return np.concatenate([fs.end_a, fs.end_b])
        sw_k = swaps[k]
        if sw_k is None:
            raise ValueError(f"continuity_cues: frame {k}'s tentative orientation is needed")
        sw = sw_k[:, None]
        starts = np.where(sw, fs.end_b, fs.end_a)
        ends = np.where(sw, fs.end_a, fs.end_b)
        return ends if want == "ends" else starts

    for k in range(len(frames)) if only is None else only:
        fs = frames[k]
        if len(fs) == 0:
            continue
        for nb, sign in ((k - 1, 1.0), (k + 1, -1.0)):
            if nb < 0 or nb >= len(frames):
                continue
            first, second = (nb, k) if nb < k else (k, nb)
            gap = timings[second].t_s - timings[first].t_s - timings[first].exposure_s
            if gap < 0 or gap > 4 * max(timings[first].exposure_s, 1e-3):
                continue  # overlapping or far-apart exposures: no usable continuity
            t = tree(nb, "ends" if nb < k else "starts")
            if t is None:
                continue
            if k not in bases:
                bases[k] = _extrapolation_basis(fs, timings[k])
            ext_a, ext_b, unc = _extrapolated_ends(fs, timings[k], gap, bases[k])
            radius = errors.continuity_radius * unc
            area = np.pi * radius**2
            d_a, n_a = nearest_and_count(ext_a, t, radius)
            d_b, n_b = nearest_and_count(ext_b, t, radius)
            q = errors.continuity_present
            at_a = continuity_llr(d_a, unc, np.maximum(n_a - 1, 1) / area, q)
            at_b = continuity_llr(d_b, unc, np.maximum(n_b - 1, 1) / area, q)
            # Previous frame (sign +1): an end near ext_a supports "A is the start".
            out[k] += sign * (at_a - at_b)
    return [np.clip(o, -errors.max_llr, errors.max_llr) for o in out]


def combine(llr: np.ndarray) -> Orientation:
    """Decide from per-cue LLRs ``(N, 3)`` (:data:`CUE_NAMES` order)."""
    total = llr.sum(axis=1)
    swap = total < 0
    confidence = 1.0 / (1.0 + np.exp(-np.abs(total)))
    agree = np.where(swap[:, None], -llr, llr)
    best = np.argmax(agree, axis=1)
    source = [
        CUE_NAMES[b] if agree[i, b] > 0 and total[i] != 0 else "none" for i, b in enumerate(best)
    ]
    return Orientation(swap=swap, confidence=confidence, source=source, llr=llr)
