"""rigs: recording rigs for BlurTrack.

Device drivers selected by URL (:mod:`rigs.imu` for serial IMUs speaking :mod:`rigs.protocol`,
:mod:`rigs.camera` for OpenCV cameras and video files), virtual devices (:mod:`rigs.fake_imu`
on a pseudo-terminal, :mod:`rigs.fake_camera`, :mod:`rigs.sim.shared_rig` for the :mod:`rigs.sim`
laser-grid simulator), the crash-safe recorder (:mod:`rigs.recorder`, :mod:`rigs.reclog`),
device-to-host time mapping (:mod:`rigs.timesync`), conversion to session folders
(:mod:`rigs.convert`) and the ``record`` / ``recover`` commands (:mod:`rigs.cli`).
"""
