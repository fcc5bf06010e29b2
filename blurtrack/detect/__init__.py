"""Laser-dot streak detection: from frames to measured blur trajectories (docs/detection.md).

Modules: :mod:`~blurtrack.detect.image` (frame preparation, background, hot pixels),
:mod:`~blurtrack.detect.context` (the frame context every stage takes),
:mod:`~blurtrack.detect.lines.segment` (components, coarse centre lines),
:mod:`~blurtrack.detect.lines.skeleton` (folded, crossing and looped streaks),
:mod:`~blurtrack.detect.lines.centreline` and :mod:`~blurtrack.detect.lines.ragged` (batched
sub-pixel centre lines and profiles), :mod:`~blurtrack.detect.lines.gaps` (streaks touching end
to end),
:mod:`~blurtrack.detect.lines.endpoints` and :mod:`~blurtrack.detect.lines.shortfit` (endpoints),
:mod:`~blurtrack.detect.lines.measure` (measuring a set of lines),
:mod:`~blurtrack.detect.separation.separate` and :mod:`~blurtrack.detect.separation.templates`
(template separation of touching streaks), :mod:`~blurtrack.detect.separation.quality` (shape
consistency, quality flag), :mod:`~blurtrack.detect.frame` (one frame), :mod:`~blurtrack.allocator`
(allocator tuning), :mod:`~blurtrack.detect.orientation` and
:mod:`~blurtrack.detect.timeshift` (which end is the start), :mod:`~blurtrack.detect.session`
(a whole session), :mod:`~blurtrack.detect.table` (the streak table),
:mod:`~blurtrack.detect.overlay` (pictures),
:mod:`~blurtrack.testing.streak_frames` and :mod:`~blurtrack.testing.mini_session` (exact test
data).
"""

from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks, detect_frame
from blurtrack.detect.params import DetectParams

__all__ = ["FLAG_NAMES", "DetectParams", "FrameStreaks", "detect_frame"]
