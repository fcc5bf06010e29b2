"""Laser-dot streak detection: from frames to measured blur trajectories (docs/detection.md).

One frame (:func:`~blurtrack.detect.frame.detect_frame`), top to bottom:
:mod:`~blurtrack.detect.image` (gray, background and noise, hot pixels, smoothing);
:mod:`~blurtrack.detect.context` (the frame context every stage reads);
:mod:`blurtrack.detect.lines` (components, centre lines, widths, endpoints: measured lines);
:mod:`blurtrack.detect.separation` (touching and crossing streaks separated, the frame's shape
consensus, the ``quality_ok`` flag and its reason); :mod:`~blurtrack.detect.trust` with
:mod:`~blurtrack.detect.flattop` (point light or extended source, trustworthy ends).

A session (:func:`~blurtrack.detect.session.pipeline.detect_session`): every frame's first pass in
forked workers (:mod:`~blurtrack.detect.forkmap`); the gyro's stages
(:mod:`blurtrack.detect.gyro`, in order in :mod:`~blurtrack.detect.gyro.gyrostages`: the
time-shift scan of :mod:`~blurtrack.detect.gyro.timeshift`, the readout order, the gyro's
direction, the session calibration, the gyro-template pass, the gyro's check); which end is
the start (:mod:`~blurtrack.detect.session.orientation`, :mod:`~blurtrack.detect.session.cues`); the
streak table (:mod:`~blurtrack.detect.session.table`). Still photographs, each a frame of its
own: :mod:`~blurtrack.detect.photos`. Pictures: :mod:`~blurtrack.detect.overlay`.
Parameters: :class:`~blurtrack.detect.params.DetectParams`, one section per stage
(:mod:`~blurtrack.detect.paramsections`, declared by :mod:`~blurtrack.detect.paramfields`).
Exact test data: :mod:`blurtrack.testing.streak_frames`, :mod:`blurtrack.testing.mini_session`.
"""

from blurtrack.detect.frame import FLAG_NAMES, FrameStreaks, detect_frame
from blurtrack.detect.params import DetectParams

__all__ = ["FLAG_NAMES", "DetectParams", "FrameStreaks", "detect_frame"]
