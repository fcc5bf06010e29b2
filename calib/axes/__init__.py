"""Camera–IMU axis discovery: which of the 24 proper signed axis permutations the data choose.

The stage modules (this package imports none of them):

- :mod:`calib.axes.rotations`: each frame pair's rotation measured from the images alone.
- :mod:`calib.axes.search`: the candidates, the scored search over the 24 permutations
  against the gyro, and its refusals.
- :mod:`calib.axes.laser`: the search on laser-dot streak time midpoints.
- :mod:`calib.axes.translation`: a pair's rotation under forward translation (a zoom about
  the focus of expansion).
- :mod:`calib.axes.heading`: the common-heading model, consulted when the pure-rotation
  search does not decide.
"""
