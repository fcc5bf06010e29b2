"""The gyro's check of ``quality_ok`` ends: a per-frame test that no single-streak image measure
can make (issue 45).

Every streak of a frame is the same camera motion seen from a different pixel, so the gyro
predicts each one's start-to-end vector and the curve between
(:func:`blurtrack.detect.gyro.gyrocurve.predict_curves`, at the streak's measured time
midpoint). Two things follow, checked on the streaks the image found ``quality_ok``:

- ``gyro_mismatch``: the measured start-to-end vector against the predicted one, after the
  session's calibration error fitted to first order: the initial calibration's focal length,
  principal point, ``R_cam_imu`` (three angles), time offset, readout, gyro bias (three
  rates) and the gyro's scale and cross-axis terms (six) are the session's, the same for
  every frame, so the predicted vectors ``p`` of all the checked frames change with them by
  ``J d`` (``J``: the prediction's Jacobian, by finite
  differences over perturbed models; ``d``: the error). ``d`` is fitted robustly,
  orientation-free, over a sample of the ``quality_ok`` streaks spread over every checked
  frame, and the residual ``|m - q|`` tested, ``q`` the vector that the calibration corrected
  by ``d`` predicts (``p + J d`` but for the curvature of a few steps; the sample, the fit and
  the correction are :mod:`blurtrack.detect.gyro.sessioncalib`'s ``fit_sample``,
  ``session_fit`` and ``corrected_model``). The vector is the difference of the two ends, so
  an end ``e`` px off moves it by ``e``: a residual above ``source.gyro_vector_tol_px`` means
  an end is off by about that much. Seventeen unknowns for the whole session cannot absorb a
  bias that one frame's streaks share (saturated ends 2-3 px long in one frame), which a fit
  per frame does. Where the corrected model does not cover a frame, or the session has too
  few voters (or a fit far off), the frame's own similarity ``m = z p``
  (:func:`vector_residual`, :data:`~blurtrack.detect.gyro.framecheck.MIN_VOTERS` at least,
  else not checked) is the fallback.
- ``hairpin``: where the shake turns within the exposure, the dot's path doubles back, and the
  streak's visible extremities are its turning points, not its start and end: the distance
  from the predicted start (end) to the predicted path's extremity beyond it along the chord,
  where the image's line ends (:func:`hairpin_depth`), is how far the measured ends are off
  (a hook that turns sideways at an end puts that extremity off the chord: along the chord
  alone, ``dense`` seed 10's hooks of 2-3 px measured 0.2-0.4 px). Above
  ``source.hairpin_depth_px`` the ends are not trusted, unless the gyro-template pass measured
  that streak along its predicted curve (:attr:`~blurtrack.detect.frame.FrameStreaks.along_curve`:
  a hairpin as its two arms).

The two tolerances share the 2 px end gate of the contract (``quality_ok`` ends within 2 px):
three quarters to the measured vector, one quarter to the unseen depth
(:class:`blurtrack.detect.params.SourceParams`); where a frame's prediction is off, its
tolerances fall by that frame's model error (:func:`frame_tolerances`). Without a gyro
nothing here runs: a hairpin is then seen by the image only where it is wide enough to fold
the streak (``looped``, shape).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.detect.forkmap import Jobs, batch_positions, fork_map
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.calibsteps import corrected_model
from blurtrack.detect.gyro.framecheck import (
    GyroCheck,
    apply_check,
    frame_tolerances,
    hairpin_depth,
    vector_residual,
)
from blurtrack.detect.gyro.gyrocurve import predict_curves
from blurtrack.detect.gyro.sessioncalib import session_fit
from blurtrack.detect.params import SourceParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import CoverageError

#: Samples per predicted curve (uniform in time): at a turn the dot is slow, so its depth is
#: sampled to a small fraction of a pixel (the rest of the curve is only needed at its ends):
#: a turn of rate ``w`` px/s^2 by at most ``w (T / 32)^2 / 2`` (T the exposure), ~0.05 px on
#: a 24 px excursion turning at 3/4 of the exposure, a tenth of ``source.hairpin_depth_px``
#: (33 samples: a quarter of that, 2 of 44 726 streaks of a 150-frame dense session otherwise,
#: both right; at 1.5x the predictions' time).
PATH_SAMPLES = 17
#: Streaks per batched model call (bounds the temporaries: samples x streaks points).
BATCH_STREAKS = 4000


def _batches(frames: Sequence[FrameStreaks], size: int = BATCH_STREAKS) -> list[list[int]]:
    """The positions of the frames with streaks, in order, in batches of at most ``size``
    streaks (a larger frame alone)."""
    return batch_positions(((k, len(fs)) for k, fs in enumerate(frames) if len(fs)), size)


def _predicted_batch(
    frames: Sequence[FrameStreaks] | Sequence[_Pending],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    samples: int,
) -> list[np.ndarray | None]:
    """:func:`predicted_curves` of the frames ``group`` (one batch of :func:`_batches`): one
    model call, frame by frame where it fails (only those the gyro misses are lost)."""
    ref = np.concatenate([frames[k].time_mid for k in group])
    ft = np.concatenate([np.full(len(frames[k]), timings[k].t_s) for k in group])
    ex = np.concatenate([np.full(len(frames[k]), timings[k].exposure_s) for k in group])
    try:
        pts = predict_curves(model, ref, ft, ex, samples).pts
    except CoverageError:
        out: list[np.ndarray | None] = [None] * len(group)
        if len(group) == 1:
            return out
        for j, k in enumerate(group):
            with contextlib.suppress(CoverageError):
                out[j] = predict_curves(
                    model, frames[k].time_mid, timings[k].t_s, timings[k].exposure_s, samples
                ).pts
        return out
    bounds = np.cumsum([len(frames[k]) for k in group])[:-1]
    return list(np.split(pts, bounds))


def predicted_curves(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    samples: int = PATH_SAMPLES,
) -> list[np.ndarray | None]:
    """``(N, samples, 2)`` predicted curves of each frame's streaks at their time midpoints
    (None where the gyro falls short), batched over frames (:func:`_batches`). ``samples=2``
    gives the two ends alone at a fraction of the cost (from a coarser grid of the
    orientation: :func:`predict_curves`)."""
    out: list[np.ndarray | None] = [None] * len(frames)
    for group in _batches(frames):
        for k, c in zip(
            group, _predicted_batch(frames, timings, model, group, samples), strict=True
        ):
            out[k] = c
    return out


def _vectors_of_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    depth: bool,
) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
    """Per frame of ``group``: the predicted start-to-end vectors ``(N, 2)`` and, with
    ``depth``, the :func:`hairpin_depth` of the whole predicted paths (:data:`PATH_SAMPLES`;
    without, only the two ends are predicted); None where the gyro falls short. All that
    :func:`check_frames` needs of a model's curves, so that little comes back from a worker."""
    curves = _predicted_batch(frames, timings, model, group, PATH_SAMPLES if depth else 2)
    return [
        None if c is None else (c[:, -1] - c[:, 0], hairpin_depth(c) if depth else None)
        for c in curves
    ]


@dataclass(frozen=True)
class _Pending:
    """A frame's streaks still to predict: their time midpoints ``(n, 2)`` (px)."""

    time_mid: np.ndarray

    def __len__(self) -> int:
        return len(self.time_mid)


def _known_paths(
    frames: Sequence[FrameStreaks], pos: Sequence[int], known: Mapping[int, np.ndarray]
) -> tuple[dict[int, np.ndarray], list[_Pending]]:
    """Of ``frames`` (``pos``: their positions in ``known``'s keys), the known curves of the
    streaks inside the image, by frame (only those of :data:`PATH_SAMPLES`, one per inside
    streak), and per frame the streaks still to predict (all, or the clipped ones)."""
    have: dict[int, np.ndarray] = {}
    pending: list[_Pending] = []
    for j, (fs, k) in enumerate(zip(frames, pos, strict=True)):
        c = known.get(k)
        inside = ~fs.flags["clipped"] if len(fs) else np.zeros(0, bool)
        if c is not None and c.shape == (int(inside.sum()), PATH_SAMPLES, 2):
            have[j] = c
            pending.append(_Pending(fs.time_mid[~inside]))
        else:
            pending.append(_Pending(fs.time_mid))
    return have, pending


def _path_batches(
    frames: Sequence[FrameStreaks], pending: Sequence[_Pending], size: int = BATCH_STREAKS
) -> list[list[int]]:
    """The positions of the frames with streaks, in order, in batches of at most ``size``
    streaks to predict, or a frame's depth to measure (an eighth of a predicted streak's
    cost); exactly :func:`_batches` where every streak is pending."""
    weighted = (
        (k, len(todo) if len(todo) == len(fs) else len(todo) + len(fs) // 8)
        for k, (fs, todo) in enumerate(zip(frames, pending, strict=True))
        if len(fs)
    )
    return batch_positions(weighted, size)


def _paths_of_batch(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    model: Any,
    group: Sequence[int],
    have: Mapping[int, np.ndarray],
    pending: Sequence[_Pending],
) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
    """:func:`_vectors_of_batch` (with the depth) of the frames ``group``, their ``pending``
    streaks predicted in one model call, the rest taken from ``have``."""
    todo = [k for k in group if len(pending[k])]
    pred = dict(
        zip(todo, _predicted_batch(pending, timings, model, todo, PATH_SAMPLES), strict=True)
        if todo
        else ()
    )
    out: list[tuple[np.ndarray, np.ndarray | None] | None] = []
    for k in group:
        c = pred.get(k) if len(pending[k]) else np.zeros((0, PATH_SAMPLES, 2))
        if c is not None and k in have:
            inside = ~frames[k].flags["clipped"]
            whole = np.empty((len(frames[k]), PATH_SAMPLES, 2))
            whole[inside] = have[k]
            whole[~inside] = c
            c = whole
        out.append(None if c is None else (c[:, -1] - c[:, 0], hairpin_depth(c)))
    return out


def check_frames(
    frames: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
    p: SourceParams,
    workers: int = 1,
    *,
    meanwhile: Callable[[], None] | None = None,
    known: Mapping[int, np.ndarray] | None = None,
    fitted: bool = False,
    jobs: Jobs | None = None,
    nominal: Any | None = None,
    batch_streaks: int = BATCH_STREAKS,
) -> int:
    """Apply the check to the ``covered`` frames' ``quality`` in place; returns how many
    frames were checked (those with a prediction and enough ``quality_ok`` streaks). Each
    checked frame keeps its streaks' residuals and its model error
    (:attr:`~blurtrack.detect.frame.FrameStreaks.gyro_residual_px`,
    :attr:`~blurtrack.detect.frame.FrameStreaks.gyro_model_error_px`). The
    vectors are tested against the session's fit where the corrected model predicts the frame
    (the calibration error :func:`~blurtrack.detect.gyro.sessioncalib.session_fit` fits over
    a sample of the voters, applied by
    :func:`~blurtrack.detect.gyro.calibsteps.corrected_model`; the residual ``|m - q|``,
    orientation-free, ``q`` that model's predicted vector), else against the frame's
    similarity.

    The model's whole paths (batch by batch: each batch the very model call of one process)
    are predicted in ``workers`` forked processes (:func:`blurtrack.detect.forkmap.fork_map`),
    the same numbers as in one; meanwhile this process runs ``meanwhile`` (first, without
    workers), the fit and the corrected model's predictions. ``known``: by position in
    ``frames``, the curves ``(n_inside, PATH_SAMPLES, 2)`` this very model predicted for a
    frame's streaks inside the image (the template pass's gate,
    :attr:`blurtrack.detect.gyro.refinepass.TemplatePass.curves`): only its other streaks
    are predicted here. ``fitted``: ``model`` is already corrected by the session's error
    fitted over these very streaks (:mod:`blurtrack.detect.gyro.sessioncalib`, no frame
    changed since): the vectors are tested against its own predictions, with no fit again.
    ``jobs``: side work computed in the same workers ahead of the batches
    (:class:`~blurtrack.detect.forkmap.Jobs`). ``nominal``: the calibration the fit's prior
    on the gyro's scale terms is centred on (None: ``model``'s;
    :func:`~blurtrack.detect.gyro.sessioncalib.session_fit`). ``batch_streaks``: streaks per
    model call (:data:`BATCH_STREAKS`; the numbers do not depend on it)."""
    if batch_streaks < 1:
        raise ValueError(f"check_frames: batch_streaks must be at least 1, got {batch_streaks}")
    keep = [k for k in covered if frames[k].quality is not None]
    sub = [frames[k] for k in keep]
    tim = [timings[k] for k in keep]
    batches = _batches(sub, batch_streaks)
    have, pending = _known_paths(sub, keep, known or {})
    groups = _path_batches(sub, pending, batch_streaks)
    fixed: list[list[tuple[np.ndarray, np.ndarray | None] | None]] = []

    def fit_meanwhile() -> None:
        if meanwhile is not None:
            meanwhile()
        if fitted:
            return
        d = session_fit(sub, tim, model, nominal=nominal)
        if d is None:
            return
        fix = corrected_model(model, d)
        out: list[tuple[np.ndarray, np.ndarray | None] | None] = [None] * len(sub)
        for group in batches:
            for k, v in zip(
                group, _vectors_of_batch(sub, tim, fix, group, depth=False), strict=True
            ):
                out[k] = v
        fixed.append(out)

    def one(b: int) -> list[tuple[np.ndarray, np.ndarray | None] | None]:
        if not have:  # nothing known: the very batches and model calls of _vectors_of_batch
            return _vectors_of_batch(sub, tim, model, groups[b], depth=True)
        return _paths_of_batch(sub, tim, model, groups[b], have, pending)

    main: list[tuple[np.ndarray, np.ndarray | None] | None] = [None] * len(sub)
    for b, got in zip(
        range(len(groups)),
        fork_map(one, range(len(groups)), workers, 1, fit_meanwhile, jobs),
        strict=True,
    ):
        for k, v in zip(groups[b], got, strict=True):
            main[k] = v
    checked = 0
    for j, (fs, c) in enumerate(zip(sub, main, strict=True)):
        if c is None or fs.quality is None:
            continue
        ok0 = np.asarray(fs.quality[2], bool)
        m = fs.end_b - fs.end_a
        pv, depth = c
        assert depth is not None  # the model's own paths: whole
        v = fixed[0][j] if fixed else (c if fitted else None)
        if v is not None:
            res = np.minimum(np.hypot(*(m - v[0]).T), np.hypot(*(m + v[0]).T))
        else:
            res = vector_residual(m, pv, ok0)
        chk = GyroCheck(np.asarray(res, float), depth)
        fs.gyro_residual_px = chk.residual
        if np.all(np.isnan(chk.residual)) and not np.any(ok0):
            continue
        tol = frame_tolerances(chk.residual, ok0, depth, p)
        fs.gyro_model_error_px = tol.model_error_px
        fs.set_verdict(*apply_check(fs, chk, p, tol))
        checked += 1
    return checked
