"""The gyro-template second pass over a session's covered frames, in worker processes.

:func:`blurtrack.detect.gyro.gyropass.refine_frame` frame by frame: each frame's refinement needs
only its own first-pass streaks, its image and the session's blur model (with the time shift
the scan found), so the frames are refined in forked workers after the scan, in order, with
exactly the result of one process.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from blurtrack.detect.forkmap import Jobs, fork_map
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyropass import FrameOutcome, refine_frame
from blurtrack.detect.gyro.sessionframes import SessionFrames
from blurtrack.detect.separation.quality import frame_quality


@dataclass
class TemplatePass:
    """What the template pass did over a session: ``frames``, the count of frames per
    outcome status (``skipped``, ``refused``, ``refined``); over the refined frames, the
    ``candidates`` (components the first pass could not have right), those ``replaced`` by
    the pass's streaks and the ``streaks`` it measured. Candidates not replaced keep their
    first-pass lines, less those far longer or shorter than their predicted curves (chains
    the pass could not split, remnants): what the pass could not do, per session."""

    frames: dict[str, int] = field(default_factory=dict)
    candidates: int = 0
    replaced: int = 0
    streaks: int = 0
    #: Per frame the pass left as it was (its position in ``found``): the gate's predicted
    #: curves ``(n_inside, gyrogate.GATE_SAMPLES, 2)`` of its streaks inside the frame, for the
    #: check.
    curves: dict[int, np.ndarray] = field(default_factory=dict)


def refine_frames(
    frames: SessionFrames,
    covered: Sequence[int],
    model: Any,
    jobs: Jobs | None = None,
    fitted: bool = False,
) -> TemplatePass:
    """:func:`refine_frame` on the ``covered`` frames (positions in ``frames.found``, which is
    updated in place; the images re-read only for the frames the gate lets through), in
    ``frames.workers`` forked processes (the same result as in one), with ``frames.params``.
    ``jobs``: side work on the frames as they were (the first pass's cues), computed in the
    same workers ahead of the frames (before any frame without workers;
    :class:`~blurtrack.detect.forkmap.Jobs`). ``fitted``: ``model`` is the session's
    corrected one (the gate then also tests the streaks' vectors, ``vectors``)."""
    found, timings, params = frames.found, frames.timings, frames.params
    out = TemplatePass()
    # The dot's cross-section is the optics', the same in every frame; a hairpin frame's own
    # (measured on lines down the middle of both arms) is too wide. The session's median.
    sig = [fs.sigma_c_px for fs in found if len(fs)]
    sigma_c = float(np.median(sig)) if sig else None

    def one(k: int) -> tuple[FrameStreaks | None, FrameOutcome, np.ndarray | None]:
        # (None: as it was; then the gate's curves, where it predicted them)
        fs = found[k]
        seen: list[np.ndarray] = []
        out, what = refine_frame(
            partial(frames.read_image, k),
            fs,
            timings[k],
            model,
            params,
            sigma_c,
            seen,
            params.source.gyro_vector_tol_px if fitted else None,
        )
        if out is fs:
            return None, what, seen[0] if seen else None
        out.quality, out.one_doubt = frame_quality(out, params)
        return out, what, None

    results = fork_map(one, covered, frames.workers, 1, None, jobs)
    for k, (changed, what, curves) in zip(covered, results, strict=True):
        if changed is not None:
            found[k] = changed
        elif curves is not None:
            out.curves[k] = curves
        out.frames[what.status] = out.frames.get(what.status, 0) + 1
        if what.status == "refined":
            out.candidates += what.candidates
            out.replaced += what.replaced
            out.streaks += what.streaks
    return out
