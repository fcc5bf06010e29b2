"""Laser-dot streak detection: from frames to measured blur trajectories.

Modules: :mod:`~blurtrack.detect.image` (frame preparation), :mod:`~blurtrack.detect.segment`
(components, coarse centre lines), :mod:`~blurtrack.detect.skeleton` (folded streaks),
:mod:`~blurtrack.detect.centreline` and :mod:`~blurtrack.detect.endpoints` (sub-pixel
measurement), :mod:`~blurtrack.detect.frame` (one frame).
"""

from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks, detect_frame
from blurtrack.detect.params import DetectParams

__all__ = ["FLAG_NAMES", "DetectParams", "FrameStreaks", "detect_frame"]
