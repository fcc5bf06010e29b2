"""The session's frames as the gyro's stages read them (:mod:`blurtrack.detect.gyro.gyrostages`,
:mod:`blurtrack.detect.gyro.sessionmodel`, :mod:`blurtrack.detect.gyro.refinepass`): one object
instead of the same six arguments to every stage, as
:class:`~blurtrack.detect.context.FrameContext` is for one frame's stages."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming


@dataclass(frozen=True)
class SessionFrames:
    """The frames a session's detection works on, after their first pass.

    - ``session``: the loaded :class:`~blurtrack.io.session.Session` (its images re-read where
      a stage needs them).
    - ``found``: per frame, its streaks; the template pass and the gyro's check change the
      list's items in place.
    - ``timings``: per frame, its start and exposure (camera clock, seconds).
    - ``idx``: per frame, its index in the session (frames are positions in ``found``
      everywhere else; ``idx`` names them in messages and re-reads their images).
    - ``params``: the detection parameters.
    - ``workers``: the processes the stages fork (1: this one; the result does not depend on
      it).
    """

    session: Any
    found: list[FrameStreaks]
    timings: list[FrameTiming]
    idx: list[int]
    params: DetectParams
    workers: int = 1

    def read_image(self, k: int) -> Any:
        """The image of the frame at position ``k``, as stored."""
        return self.session.read_image(self.idx[k])
