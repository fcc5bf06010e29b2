"""Feature tracking of a natural-scene session with each frame pair's image rotation measured
on the thread that tracked it.

The axis search needs every pair's rotation (:func:`calib.axes.rotations.pair_rotation`), which
depends only on the pair's own tracks. Measured inside :func:`blurtrack.features.pairs.map_pairs`'s
work on a pair, its numpy work (which holds the GIL) overlaps the other thread's decoding and
Lucas–Kanade (which do not), instead of running on one core after tracking (0.9 s for 10 s of
720p). The tracks and rotations are those of :func:`blurtrack.features.tracks.track_frames`
followed by :func:`calib.natural.pipeline.image_rotations`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from blurtrack.features.pairs import map_pairs
from blurtrack.features.tracks import (
    FeatureTrackError,
    FeatureTracks,
    TrackParams,
    to_gray8,
    track_pair,
    tracks_of_pairs,
)
from blurtrack.geometry.calibration import Calibration
from calib.axes.rotations import PairRotation, pair_rotation
from calib.axes.translation import fit_rotation_translating


def track_and_rotate(
    read_frame: Callable[[int], np.ndarray],
    frame_t_ns: np.ndarray,
    exposure_ns: np.ndarray,
    initial: Calibration,
    params: TrackParams,
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
    meanwhile: Sequence[Callable[[], object]] = (),
) -> tuple[FeatureTracks, list[PairRotation | None]]:
    """Tracks of every consecutive frame pair and each pair's rotation (``None`` where too few
    points; gather them with :func:`calib.axes.rotations.collect_rotations`), translation a
    nuisance where the data need it (:mod:`calib.axes.translation`); times relative to the
    first frame.

    ``meanwhile``: calls run on one more thread while the frames are tracked, for work the
    calibration needs next whose result they keep themselves (the gyro's resampling,
    :meth:`~blurtrack.geometry.gyro.GyroTrace.upsampled`, and its scipy import: 0.5 s off the
    critical path). Their errors are ignored here: the later call meets them again."""
    ts = np.asarray(frame_t_ns, np.int64)
    n = int(ts.size)
    if n < 2:
        raise FeatureTrackError(f"feature tracks need at least 2 frames, got {n}")
    t = (ts - ts[0]) * 1e-9
    e = np.asarray(exposure_ns, np.int64) * 1e-9
    cam = initial.camera

    def work(f: int, a: np.ndarray, b: np.ndarray) -> tuple[tuple, PairRotation | None]:
        tr = track_pair(a, b, params)
        return tr, pair_rotation(tr[0], tr[1], f, t, e, cam, pair_fit=fit_rotation_translating)

    with ThreadPoolExecutor(max_workers=1) as side:
        pending = [side.submit(c) for c in meanwhile]
        done = map_pairs(work, lambda i: to_gray8(read_frame(i)), range(n - 1), workers, progress)
        for p in pending:
            p.exception()  # waits; an error is raised again where the result is needed
    return tracks_of_pairs([d[0] for d in done], n), [d[1] for d in done]
