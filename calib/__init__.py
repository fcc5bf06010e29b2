"""CasADi calibration of the gyro blur model (see docs/calibration.md).

Modules: :mod:`calib.params` (parameter vector), :mod:`calib.data` (streaks, hold-out),
:mod:`calib.problem` (the per-streak residual from blurtrack.geometry.kernels),
:mod:`calib.grid` (residuals and exact CasADi Jacobians on a fixed orientation grid),
:mod:`calib.tracks` (inter-frame tracks of streak midpoints, the default final-stage
residual), :mod:`calib.centreline` (centre-line residuals on the grid),
:mod:`calib.framenoise` (frame-correlated gyro-noise GLS), :mod:`calib.init`
(time-shift and focal search), :mod:`calib.solve` (robust Levenberg–Marquardt),
:mod:`calib.uncertainty` (sigma, observability), :mod:`calib.fit` (the driver),
:mod:`calib.result` (result objects), :mod:`calib.export` (OpenVINS, ROS camera_info),
:mod:`calib.testing` (known-truth problems), :mod:`calib.cli` (``calibrate``, ``report``).
"""
