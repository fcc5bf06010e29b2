"""Natural-scene calibration: feature tracks between frames instead of laser streaks.

The stages, in pipeline order (this package imports none of them):

- :mod:`calib.natural.cli`: the natural-scene and axis-search parts of ``blurtrack calibrate``.
- :mod:`calib.natural.pipeline`: the calibration itself, :func:`calibrate_natural
  <calib.natural.pipeline.calibrate_natural>`, which runs the stages below.
- :mod:`calib.natural.pairs`: feature tracking, each frame pair's image rotation measured on
  the thread that tracked it (for the axis search, :mod:`calib.axes.search`).
- :mod:`calib.natural.blur`: tracked points as mid-exposure positions (equal-blur refinement).
- :mod:`calib.natural.scale`: the gyro scale fitted under a prior.
- :mod:`calib.natural.sigma`: honest 1-sigma (correlated tracks, the unfitted gyro scale),
  with :mod:`calib.natural.scene`: the scene clusters of the tracks.
- :mod:`calib.natural.motion`: the camera's translation as a nuisance (driving scenes).
- :mod:`calib.natural.travel`: a rotation-only fit refitted with the translation, its hold-out.
- :mod:`calib.natural.motion_sigma`: honest 1-sigma of translation fits.
"""
