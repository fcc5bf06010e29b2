"""The gyro-template pass: a second detection pass with the gyro's predicted streak shape as
the template, and the time shift those templates refine.

Modules in pipeline order: :mod:`~blurtrack.detect.gyro.gyrocurve` (the predicted curves and
their templates), :mod:`~blurtrack.detect.gyro.gyroshape` (the shape search),
:mod:`~blurtrack.detect.gyro.gyroconfirm` (whether the measured lines confirm the placed curves),
:mod:`~blurtrack.detect.gyro.gyromeasure` (measurement of the placements),
:mod:`~blurtrack.detect.gyro.gyropass` (the pass over one frame),
:mod:`~blurtrack.detect.gyro.shiftfit` (the camera-IMU time shift refined by the templates),
:mod:`~blurtrack.detect.gyro.refinepass` (the pass over a session's frames, in workers).
"""
