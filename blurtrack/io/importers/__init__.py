"""Importers that turn third-party recordings into session folders (docs/conventions.md).

One module per source; the two real recordings of ``../shared/data/real`` are covered:

- ``deepgyro``: DeepGyro's SHIELD tablet burst (``images/images.txt`` with ``timestamp_ns
  exposure_ns`` per frame, ``imu/imu.txt`` Android sensor log ``type timestamp_ns x y z``).
- ``marslogger``: the MARS logger app (``movie_metadata.csv``, ``video_frames/frame<i>.jpg``,
  ``gyro_accel.csv``, optionally ``calib.npz``).
- ``euroc``: EuRoC/ASL folders (``mav0/cam0``, ``mav0/imu0``, ``sensor.yaml`` with ``T_BS``).
- ``rosbag``: ROS 1 ``.bag`` files and ROS 2 bags (``sensor_msgs/Image``, ``CompressedImage``,
  ``Imu``, optionally ``CameraInfo``), via ``rosbags``.
- ``video``: a video file decoded with OpenCV plus a Gyroflow ``.gcsv`` gyro log.
- ``frames``: a folder of frames, a frame-times file and a gyro CSV (the commonest lab layout).

What the sources do not say (time offset, readout, axis signs) is filled with stated
assumptions, recorded under ``import.assumptions`` in ``session.yaml``; they are guesses for the
calibration to refine, not truth. No importer passes a guessed camera–IMU axis mapping as known:
unless the source states a proper rotation (EuRoC's ``T_BS``, a Kalibr file), the session says
``imu: {axes_known: false}`` and ``calibrate`` scores the 24 signed axis permutations.
"""

from __future__ import annotations

from blurtrack.io.importers.deepgyro import import_deepgyro
from blurtrack.io.importers.euroc import import_euroc
from blurtrack.io.importers.frames import import_frames
from blurtrack.io.importers.marslogger import fit_radtan4, import_marslogger
from blurtrack.io.importers.rosbag import import_rosbag
from blurtrack.io.importers.video import import_video

IMPORTERS = {
    "deepgyro": import_deepgyro,
    "marslogger": import_marslogger,
    "euroc": import_euroc,
    "rosbag": import_rosbag,
    "video": import_video,
    "frames": import_frames,
}
#: The options each importer takes (keyword arguments) beyond ``src`` and ``out``.
IMPORTER_OPTIONS = {
    "deepgyro": (),
    "marslogger": (),
    "euroc": ("exposure_s", "readout_s", "stamp", "max_frames"),
    "rosbag": (
        "image_topic",
        "imu_topic",
        "exposure_s",
        "readout_s",
        "stamp",
        "calib",
        "max_frames",
    ),
    "video": ("gcsv", "exposure_s", "readout_s", "stamp", "max_frames"),
    "frames": (
        "images",
        "frame_times_file",
        "gyro",
        "gyro_columns",
        "time_unit",
        "gyro_unit",
        "exposure_s",
        "readout_s",
        "stamp",
        "intrinsics",
        "max_frames",
    ),
}

__all__ = [
    "IMPORTERS",
    "IMPORTER_OPTIONS",
    "fit_radtan4",
    "import_deepgyro",
    "import_euroc",
    "import_frames",
    "import_marslogger",
    "import_rosbag",
    "import_video",
]
