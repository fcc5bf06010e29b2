"""The gyro's stages of detecting a session: the gyro checked against the images, the
session's blur model corrected, the gyro-template second pass, and the gyro's check of the
``quality_ok`` ends.

Modules in pipeline order: :mod:`~blurtrack.detect.gyro.gyrostages` (the stages in order,
after the time-shift scan of :mod:`blurtrack.detect.gyro.timeshift`),
:mod:`~blurtrack.detect.gyro.readout` (which row the sensor reads first),
:mod:`~blurtrack.detect.gyro.direction` (the gyro's motion against the images),
:mod:`~blurtrack.detect.gyro.sessionmodel` with :mod:`~blurtrack.detect.gyro.sessioncalib`
(the session's calibration error fitted to the first pass's streaks, over the parameters of
:mod:`~blurtrack.detect.gyro.calibsteps`) and
:mod:`~blurtrack.detect.gyro.shiftfit` (the time shift refined by the templates, where the
calibration is not fitted), :mod:`~blurtrack.detect.gyro.refinepass` (the template pass over
the frames, in workers) and for one frame :mod:`~blurtrack.detect.gyro.gyropass`:
:mod:`~blurtrack.detect.gyro.gyrogate` (which frames), :mod:`~blurtrack.detect.gyro.gyrocurve`
(the predicted curves and their templates), :mod:`~blurtrack.detect.gyro.gyrocandidates`
(which components), :mod:`~blurtrack.detect.gyro.gyroshape` (the shape search),
:mod:`~blurtrack.detect.gyro.gyroconfirm` (whether the measured lines confirm the curves),
:mod:`~blurtrack.detect.gyro.gyromeasure` and :mod:`~blurtrack.detect.gyro.gyroaccept`
(measurement and acceptance); last :mod:`~blurtrack.detect.gyro.gyrotrust` (the check).
The predicted curves read the camera's orientation tabulated per frame
(:mod:`blurtrack.geometry.orientation_grid`).
"""
