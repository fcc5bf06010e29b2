"""A session as a ROS bag for Kalibr, OpenVINS and other ROS tools (written with ``rosbags``).

- ROS 1 ``.bag`` (what ``kalibr_calibrate_imu_camera`` reads) or, with ``ros2=True``, a ROS 2
  bag folder with MCAP (default) or sqlite3 storage.
- ``/cam0/image_raw``: ``sensor_msgs/Image``, ``mono8``/``mono16`` for gray sessions,
  ``rgb8``/``rgb16`` for colour ones (lossless); ``/imu0``: ``sensor_msgs/Imu`` per sample with
  ``angular_velocity`` (rad/s) and ``linear_acceleration`` (m/s²; covariance[0] = -1 when the
  session has no accelerometer, REP 145's "no data"), orientation unknown (covariance[0] = -1);
  ``/cam0/camera_info``: ``sensor_msgs/CameraInfo`` (plumb_bob) with every frame.
- Header stamps (and bag times): the session's frame time, the START of the top row's exposure
  (``stamp="start"``), or the centre of the frame's exposure (``stamp="middle"``: + exposure/2
  + readout/2); IMU samples at their own stamps. A Kalibr time shift fitted on this bag refers
  to the chosen stamp.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import BlurTrackError
from blurtrack.io.calibration import ROSTOPIC as IMAGE_TOPIC
from blurtrack.io.calibration import calibration_to_dict
from blurtrack.io.rosimage import encode_raw
from blurtrack.io.session import Session

IMU_TOPIC = "/imu0"
INFO_TOPIC = "/cam0/camera_info"
STORAGES = ("mcap", "sqlite3")


class ExportError(BlurTrackError):
    """A session could not be exported."""


def _header(ts: Any, t_ns: int, frame_id: str, seq: int) -> Any:
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    stamp = Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))
    if "seq" in Header.__dataclass_fields__:
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _imu_msg(ts: Any, t_ns: int, seq: int, w: np.ndarray, a: np.ndarray | None) -> Any:
    Vec = ts.types["geometry_msgs/msg/Vector3"]
    Quat = ts.types["geometry_msgs/msg/Quaternion"]
    unknown = np.zeros(9)
    unknown[0] = -1.0
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, t_ns, "imu0", seq),
        orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=unknown,
        angular_velocity=Vec(x=float(w[0]), y=float(w[1]), z=float(w[2])),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=(
            Vec(x=0.0, y=0.0, z=0.0)
            if a is None
            else Vec(x=float(a[0]), y=float(a[1]), z=float(a[2]))
        ),
        linear_acceleration_covariance=unknown if a is None else np.zeros(9),
    )


def _info_msg(ts: Any, t_ns: int, seq: int, cam: Any) -> Any:
    """``sensor_msgs/CameraInfo``: K, plumb_bob D (k1 k2 p1 p2 k3), R = I, P = [K | 0]."""
    Info = ts.types["sensor_msgs/msg/CameraInfo"]
    fx, fy, cx, cy = cam.intrinsics
    K = np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    D = np.array([*cam.distortion_coeffs, 0.0] if cam.distortion_coeffs else [0.0] * 5)
    P = np.array([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    upper = "K" in Info.__dataclass_fields__  # ROS 1 spells the arrays D K R P
    arrays = dict(zip("DKRP" if upper else "dkrp", (D, K, np.eye(3).ravel(), P), strict=True))
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return Info(
        header=_header(ts, t_ns, "cam0", seq),
        height=cam.height,
        width=cam.width,
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        roi=roi,
        **arrays,
    )


def _writer(out: Path, ros2: bool, storage: str) -> tuple[Any, Any, Any]:
    from rosbags.typesys import Stores, get_typestore

    if out.exists():
        raise ExportError(f"refusing to overwrite {out}")
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if storage not in STORAGES:
            raise ExportError(f"storage must be one of {STORAGES}, got {storage!r}")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        ts = get_typestore(Stores.ROS2_HUMBLE)
        return Writer(out, version=9, storage_plugin=plugin), ts, ts.serialize_cdr
    from rosbags.rosbag1 import Writer as Writer1

    ts = get_typestore(Stores.ROS1_NOETIC)
    return Writer1(out), ts, ts.serialize_ros1


def export_rosbag(
    session: Session,
    out: str | Path,
    *,
    ros2: bool = False,
    storage: str = "mcap",
    stamp: str = "start",
    progress: Any = None,
) -> dict[str, Any]:
    """Write ``session`` as a bag at ``out`` (a ``.bag`` file, or a ROS 2 bag folder).

    ``progress``: optional callable called once per frame written. Returns a summary dict.
    """
    if stamp not in ("start", "middle"):
        raise ExportError(f"stamp must be 'start' or 'middle', got {stamp!r}")
    from blurtrack.io.atomic import atomic_new

    out = Path(out)
    if out.exists():
        raise ExportError(f"refusing to overwrite {out}")
    with atomic_new(out) as part:  # a full disk or Ctrl-C leaves no half bag at ``out``
        return _export(session, out, part, ros2, storage, stamp, progress)


def _export(
    session: Session, out: Path, part: Path, ros2: bool, storage: str, stamp: str, progress: Any
) -> dict[str, Any]:
    writer, ts, serialize = _writer(part, ros2, storage)
    cam = session.meta.camera
    img_type, imu_type = "sensor_msgs/msg/Image", "sensor_msgs/msg/Imu"
    offsets = np.zeros(len(session.frames), np.int64)
    if stamp == "middle":
        offsets = session.frames["exposure_ns"].to_numpy(np.int64) + round(cam.readout_s * 1e9)
        offsets //= 2
    stamps = session.frames["timestamp_ns"].to_numpy(np.int64) + offsets
    acc = session.accel_mps2
    encodings = set()
    writer.open()
    try:
        c_img = writer.add_connection(IMAGE_TOPIC, img_type, typestore=ts)
        c_imu = writer.add_connection(IMU_TOPIC, imu_type, typestore=ts)
        info_type = "sensor_msgs/msg/CameraInfo"
        c_info = writer.add_connection(INFO_TOPIC, info_type, typestore=ts)
        # Interleave in time order so readers that stream (Kalibr) see a causal bag.
        events = sorted(
            [(int(t), 0, i) for i, t in enumerate(stamps)]
            + [(int(t), 1, k) for k, t in enumerate(session.imu_t_ns)]
        )
        for t_ns, kind, i in events:
            if kind == 1:
                msg = _imu_msg(ts, t_ns, i, session.omega_radps[i], None if acc is None else acc[i])
                writer.write(c_imu, t_ns, serialize(msg, imu_type))
                continue
            enc, step, data = encode_raw(session.read_image(i))
            encodings.add(enc)
            msg = ts.types[img_type](
                header=_header(ts, t_ns, "cam0", i),
                height=cam.height,
                width=cam.width,
                encoding=enc,
                is_bigendian=0,
                step=step,
                data=np.frombuffer(data, np.uint8),
            )
            writer.write(c_img, t_ns, serialize(msg, img_type))
            writer.write(c_info, t_ns, serialize(_info_msg(ts, t_ns, i, cam), info_type))
            if progress is not None:
                progress()
    finally:
        writer.close()
    return {
        "out": str(out),
        "format": f"ROS 2 bag ({storage})" if ros2 else "ROS 1 bag",
        "topics": {
            IMAGE_TOPIC: img_type,
            INFO_TOPIC: "sensor_msgs/msg/CameraInfo",
            IMU_TOPIC: imu_type,
        },
        "frames": len(stamps),
        "imu_samples": int(session.imu_t_ns.size),
        "encodings": sorted(encodings),
        "accelerometer": acc is not None,
        "stamp": stamp,
    }


def kalibr_companions(out: str | Path) -> tuple[Path, Path]:
    """The Kalibr files written beside a bag ``out``: ``<stem>.camchain.yaml``, ``.imu.yaml``."""
    out = Path(out)
    stem = out.name[: -len(".bag")] if out.name.endswith(".bag") else out.name
    return out.with_name(stem + ".camchain.yaml"), out.with_name(stem + ".imu.yaml")


def write_kalibr_companions(session: Session, out: str | Path) -> dict[str, str]:
    """Kalibr's ``--cams`` and ``--imu`` inputs for the bag ``out`` (the session's own guesses
    for the camera; T_cam_imu is marked a guess when the session's axes are unknown)."""
    import yaml

    from blurtrack.io.kalibr_imu import write_kalibr_imu
    from blurtrack.io.yamlio import write_text_atomic

    cams, imu = kalibr_companions(out)
    for p in (cams, imu):
        if p.exists():
            raise ExportError(f"refusing to overwrite {p}")
    note = "# Kalibr camchain from the session's own guesses (session.yaml), not a calibration.\n"
    if not session.meta.imu.axes_known:
        note += "# T_cam_imu is a GUESS: the session says imu.axes_known: false.\n"
    body = yaml.safe_dump(
        calibration_to_dict(session.initial_calibration()), sort_keys=False, width=100
    )
    write_text_atomic(cams, note + body)
    source = write_kalibr_imu(session, imu, rostopic=IMU_TOPIC)
    return {"camchain": str(cams), "imu": str(imu), "imu_noise_source": source}
