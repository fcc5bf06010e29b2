"""The orientation cues of a session's frames, as the session driver
(:func:`blurtrack.detect.session.pipeline.detect_session`) computes them: the gyro and profile
LLRs of the covered frames, batched (:func:`gyro_llrs`), as side jobs of the template pass's workers
(:func:`cue_jobs`, :func:`cues_of_jobs`) and again only for the frames the pass replaced
(:func:`recomputed_where_changed`); and the continuity LLRs of the final frames
(:func:`continuity_columns`). The cues themselves are :mod:`blurtrack.detect.session.orientation`'s.
"""

from __future__ import annotations

import contextlib
from functools import partial
from itertools import pairwise
from typing import Any

import numpy as np

from blurtrack.detect.forkmap import Jobs
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.session.orientation import (
    CueErrors,
    FrameTiming,
    combine,
    continuity_cues,
    gyro_cue_batches,
    gyro_cues,
    gyro_cues_batch,
    gyro_cues_of_batch,
)
from blurtrack.errors import BlurTrackError, CoverageError


def recomputed_where_changed(
    cues: list[np.ndarray | None],
    before: list[FrameStreaks],
    after: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    error_model: CueErrors,
) -> list[np.ndarray | None]:
    """``cues`` (those of the covered frames of ``before``) with the frames that ``after``
    replaced computed again (each frame's cues depend on that frame alone)."""
    changed = [j for j, k in enumerate(covered) if after[k] is not before[k]]
    if not changed:
        return cues
    out = list(cues)
    redo = gyro_llrs(after, timings, [covered[j] for j in changed], model, error_model)
    for j, c in zip(changed, redo, strict=True):
        out[j] = c
    return out


def gyro_llrs(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    error_model: CueErrors,
) -> list[np.ndarray | None]:
    """Gyro and profile LLRs of the covered frames, batched; frame by frame (None where the
    gyro falls short after all, e.g. a point predicted outside the frame) if a batch fails."""
    try:
        return list(
            gyro_cues_batch(
                [found[k] for k in covered], [timings[k] for k in covered], model, error_model
            )
        )
    except CoverageError:
        pass
    out: list[np.ndarray | None] = []
    for k in covered:
        try:
            out.append(gyro_cues(found[k], timings[k], model, error_model))
        except CoverageError:
            out.append(None)
    return out


def cue_jobs(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    error_model: CueErrors,
) -> Jobs:
    """:func:`gyro_llrs`'s batched model calls as side jobs of a worker pool
    (:class:`~blurtrack.detect.forkmap.Jobs`): each returns its batch's cues, or the
    :class:`~blurtrack.errors.BlurTrackError` it met (:func:`cues_of_jobs` decides)."""
    sub, tim = [found[k] for k in covered], [timings[k] for k in covered]

    def job(batch: list[int]) -> list[np.ndarray] | BlurTrackError:
        try:
            return gyro_cues_of_batch(sub, tim, batch, model, error_model)
        except BlurTrackError as exc:
            return exc

    return Jobs(partial(job, b) for b in gyro_cue_batches(sub))


def cues_of_jobs(
    jobs: Jobs,
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    covered: list[int],
    model: Any,
    error_model: CueErrors,
) -> list[np.ndarray | None] | None:
    """The cues of the covered frames from :func:`cue_jobs`'s results: :func:`gyro_llrs`'s
    very values (where the batches meet a coverage error first, frame by frame, as it does),
    or None where it would have failed (left to be computed after the pass)."""
    sub = [found[k] for k in covered]
    out: list[np.ndarray | None] = [np.zeros((len(fs), 2)) for fs in sub]
    for batch, got in zip(gyro_cue_batches(sub), jobs.results, strict=True):
        if isinstance(got, CoverageError):
            with contextlib.suppress(BlurTrackError):
                return gyro_llrs(found, timings, covered, model, error_model)
            return None
        if isinstance(got, BlurTrackError):
            return None
        for j, part in zip(batch, got, strict=True):
            out[j] = part
    return out


def _continuity_into(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    llrs: list[np.ndarray],
    errors: CueErrors,
    only: range,
) -> None:
    """The continuity column of ``llrs`` (in place) of the frames ``only`` (steps of 1),
    twice: any neighbouring end first, then (with the tentative orientation of all three cues)
    only the previous frame's ends and the next frame's starts; each LLR clipped to
    ``+-errors.max_llr``. The first time also computes the frames next to ``only``, whose
    tentative orientation the second reads: each frame's column is the same as computed with
    all the frames at once."""
    n = len(found)
    near = range(max(only.start - 1, 0), min(only.stop + 1, n))
    basis: dict[int, Any] = {}  # the frames do not change between the two passes
    first = continuity_cues(found, timings, cache=basis, errors=errors, only=near)
    for k in near:
        llrs[k][:, 2] = first[k]
    tentative = [combine(llrs[k]).swap if k in near else None for k in range(n)]
    second = continuity_cues(found, timings, tentative, cache=basis, errors=errors, only=only)
    for k in only:
        llrs[k][:, 2] = second[k]


def continuity_columns(
    found: list[FrameStreaks],
    timings: list[FrameTiming],
    llrs: list[np.ndarray],
    errors: CueErrors,
    only: range | None = None,
) -> list[np.ndarray]:
    """The continuity column of the frames ``only`` (default: all; steps of 1) of ``llrs``
    (:func:`_continuity_into` on a copy: ``llrs`` stays as it is, so that this may run in a
    worker, and several parts in several workers: :func:`continuity_parts`)."""
    part = range(len(found)) if only is None else only
    if part.step != 1 or part.start < 0 or part.stop > len(found):
        raise ValueError(f"continuity_columns: frames {part} are not a run of the {len(found)}")
    cols = [llr.copy() for llr in llrs]
    if len(part):
        _continuity_into(found, timings, cols, errors, part)
    return [cols[k][:, 2] for k in part]


def continuity_parts(n_frames: int, parts: int) -> list[range]:
    """``n_frames`` frames cut into at most ``parts`` consecutive ranges of near-equal size
    (:func:`continuity_columns`'s parts, one per worker)."""
    m = max(1, min(parts, n_frames))
    cuts = [round(i * n_frames / m) for i in range(m + 1)]
    return [range(a, b) for a, b in pairwise(cuts)]
