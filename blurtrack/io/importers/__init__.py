"""Importers that turn third-party phone recordings into session folders (DESIGN.md).

Both real recordings of ``../shared/data/real`` are supported:

- ``deepgyro``: DeepGyro's SHIELD tablet burst (``images/images.txt`` with ``timestamp_ns
  exposure_ns`` per frame, ``imu/imu.txt`` Android sensor log ``type timestamp_ns x y z``).
- ``marslogger``: the MARS logger app (``movie_metadata.csv``, ``video_frames/frame<i>.jpg``,
  ``gyro_accel.csv``, optionally ``calib.npz``).

What the sources do not say (time offset, readout, axis signs) is filled with stated
assumptions, recorded under ``import.assumptions`` in ``session.yaml``; they are guesses for the
calibration to refine, not truth. No importer passes a guessed camera–IMU axis mapping as known:
unless the source states a proper rotation (EuRoC's ``T_BS``, a Kalibr file), the session says
``imu: {axes_known: false}`` and ``calibrate`` scores the 24 signed axis permutations.
"""

from __future__ import annotations

from blurtrack.io.importers.deepgyro import import_deepgyro
from blurtrack.io.importers.marslogger import fit_radtan4, import_marslogger

IMPORTERS = {"deepgyro": import_deepgyro, "marslogger": import_marslogger}

__all__ = ["IMPORTERS", "fit_radtan4", "import_deepgyro", "import_marslogger"]
