"""ROS 1 ``.bag`` files and ROS 2 bag folders (sqlite3 or MCAP storage), read with ``rosbags``.

Frames come from one ``sensor_msgs/Image`` or ``CompressedImage`` topic, gyro (and
accelerometer) samples from one ``sensor_msgs/Imu`` topic, both stamped by their headers (the
bag's receive time where a header stamp is zero). A topic is chosen automatically only when it
is the single one of its type; otherwise ``--image-topic`` / ``--imu-topic`` decide, and a wrong
name is refused with the list of what the bag holds. Intrinsics come from ``--calib`` (a Kalibr
or BlurTrack calibration file, which also states the axes), else a ``sensor_msgs/CameraInfo``
topic, else a stated guess; without ``--calib`` the camera–IMU axes are unknown
(``axes_known: false``). Exposure and readout are not in these messages: options.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import BlurTrackError, ImportFormatError
from blurtrack.geometry.camera import Camera
from blurtrack.io.cvyaml import read_cv_yaml
from blurtrack.io.importers.common import (
    MAX_FRAMES,
    check_readout,
    exposure_ns,
    frame_start_ns,
    guessed_intrinsics,
    rate_hz,
    sorted_unique,
)
from blurtrack.io.rosimage import decode_compressed, decode_raw
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
IMU_TYPE = "sensor_msgs/msg/Imu"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def _pick(topics: dict[str, str], wanted: str | None, types: tuple[str, ...], what: str) -> str:
    listing = ", ".join(f"{t} ({m.split('/')[-1]})" for t, m in sorted(topics.items())) or "none"
    if wanted is not None:
        if topics.get(wanted) not in types:
            raise ImportFormatError(f"rosbag: no {what} topic {wanted!r}; the bag has: {listing}")
        return wanted
    found = [t for t, m in sorted(topics.items()) if m in types]
    if len(found) != 1:
        flag = "--image-topic" if what == "image" else "--imu-topic"
        raise ImportFormatError(
            f"rosbag: {len(found)} {what} topics, choose one with {flag}; the bag has: {listing}"
        )
    return found[0]


def _stamp_ns(msg: Any, bag_ns: int) -> int:
    st = msg.header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(st.nanosec)
    return ns if ns > 0 else int(bag_ns)


def _image(msg: Any, msgtype: str) -> np.ndarray:
    if msgtype.endswith("CompressedImage"):
        return decode_compressed(str(msg.format), msg.data)
    return decode_raw(
        int(msg.width), int(msg.height), str(msg.encoding), int(msg.is_bigendian),
        int(msg.step), msg.data,
    )  # fmt: skip


def _frames(reader: Any, conns: list[Any]) -> Iterator[tuple[int, np.ndarray]]:
    for c, bag_ns, raw in reader.messages(conns):
        msg = reader.deserialize(raw, c.msgtype)
        yield _stamp_ns(msg, bag_ns), _image(msg, c.msgtype)


def _camera_from_info(msg: Any, readout_s: float) -> Camera:
    K = np.asarray(msg.K if hasattr(msg, "K") else msg.k, float).reshape(-1)
    D = np.asarray(msg.D if hasattr(msg, "D") else msg.d, float).reshape(-1)
    model = str(msg.distortion_model)
    if K.size != 9 or not np.all(np.isfinite(K)) or not np.all(np.isfinite(D)):
        raise ImportFormatError("rosbag: CameraInfo K must be 9 finite numbers")
    if D.size and (np.any(D[4:] != 0) or model not in ("plumb_bob", "radtan")):
        raise ImportFormatError(
            f"rosbag: CameraInfo distortion {model!r} {D.tolist()} is not radtan k1 k2 p1 p2"
        )
    dist = tuple(float(v) for v in D[:4]) if D.size and np.any(D[:4] != 0) else ()
    return Camera(
        (int(msg.width), int(msg.height)),
        (K[0], K[4], K[2], K[5]),
        "radtan" if dist else "none",
        dist,
        readout_s=readout_s,
    )


def _open(src: Path):
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    if not src.exists():
        raise ImportFormatError(f"rosbag: {src} not found")
    try:
        reader = AnyReader([src], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise ImportFormatError(f"rosbag: {src} is not a readable bag ({exc})") from None
    return reader


def import_rosbag(
    src: str | Path,
    out: str | Path,
    *,
    image_topic: str | None = None,
    imu_topic: str | None = None,
    exposure_s: float | None = None,
    readout_s: float = 0.0,
    stamp: str = "start",
    calib: str | Path | None = None,
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Import a ROS 1 or ROS 2 bag into a session; returns a summary dict."""
    from blurtrack.io.calibration import read_calibration

    src = Path(src)
    exp = exposure_ns(exposure_s, "rosbag")
    readout = check_readout(readout_s, "rosbag")
    limit = MAX_FRAMES if max_frames is None else min(int(max_frames), MAX_FRAMES)
    cal, calib_has_axes = None, False
    if calib is not None:
        try:
            cal = read_calibration(calib)
            cam0 = read_cv_yaml(calib, "calibration file")["cam0"]
            calib_has_axes = "T_cam_imu" in cam0 or "T_imu_cam" in cam0  # else camera-only
        except BlurTrackError as exc:
            raise ImportFormatError(f"rosbag --calib: {exc}") from None
    reader = _open(src)
    try:
        topics = {t: info.msgtype for t, info in reader.topics.items()}
        img_topic = _pick(topics, image_topic, IMAGE_TYPES, "image")
        imu_topic_ = _pick(topics, imu_topic, (IMU_TYPE,), "IMU")
        info_topics = [t for t, m in sorted(topics.items()) if m == INFO_TYPE]
        by_topic: dict[str, list[Any]] = {}  # a ROS 1 topic may have several connections
        for c in reader.connections:
            by_topic.setdefault(c.topic, []).append(c)
        t_imu, w_imu, a_imu, has_acc = [], [], [], True
        for conn, bag_ns, raw in reader.messages(by_topic[imu_topic_]):
            m = reader.deserialize(raw, conn.msgtype)
            t_imu.append(_stamp_ns(m, bag_ns))
            w_imu.append([m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z])
            la = m.linear_acceleration
            a_imu.append([la.x, la.y, la.z])
            has_acc &= float(m.linear_acceleration_covariance[0]) != -1.0
        t_imu_a, w, a = np.asarray(t_imu, np.int64), np.asarray(w_imu, float), np.asarray(a_imu)
        if t_imu_a.size < 2 or not (np.all(np.isfinite(w)) and np.all(np.isfinite(a))):
            raise ImportFormatError(f"rosbag: {imu_topic_} has <2 samples or non-finite values")
        sel = sorted_unique(t_imu_a)
        info_msg = None
        if cal is None and info_topics:
            conns = by_topic[info_topics[0]]
            for conn, _, raw in reader.messages(conns):
                info_msg = reader.deserialize(raw, conn.msgtype)
                break
        frames = _frames(reader, by_topic[img_topic])
        first = next(frames, None)
        if first is None:
            raise ImportFormatError(f"rosbag: {img_topic} holds no messages")
        h, w_px = first[1].shape[:2]
        assumptions: dict[str, Any] = {
            "exposure_s": f"{exp * 1e-9} (from --exposure-ms; not in the messages)",
            "readout_s": f"{readout} (from --readout-ms; 0 = global shutter)",
            "timestamps": f"image header stamps taken as the {stamp} of exposure (--stamp)",
        }
        if cal is not None:
            camera = cal.camera
            if camera.resolution != (w_px, h):
                raise ImportFormatError(
                    f"rosbag --calib is for {camera.resolution}, the images are {w_px}x{h}"
                )
            camera = Camera(
                camera.resolution, camera.intrinsics, camera.distortion_model,
                camera.distortion_coeffs, readout_s=readout or camera.readout_s,
            )  # fmt: skip
            imu = ImuConfig(
                rate_hz=rate_hz(t_imu_a[sel], imu_topic_),
                T_cam_imu=cal.T_cam_imu.tolist(),
                timeshift_cam_imu=cal.timeshift_cam_imu_s,
                axes_known=calib_has_axes,
            )
            assumptions["camera"] = f"intrinsics, axes and time shift from {calib}"
            if not calib_has_axes:
                assumptions["R_cam_imu"] = f"UNKNOWN (axes_known: false): {calib} has no T_cam_imu"
        else:
            if info_msg is not None:
                camera = _camera_from_info(info_msg, readout)
                assumptions["camera"] = f"intrinsics from {info_topics[0]} (CameraInfo)"
            else:
                camera = Camera((w_px, h), guessed_intrinsics(w_px, h), readout_s=readout)
                assumptions["camera"] = "GUESS: fx = fy = width, centred principal point"
            imu = ImuConfig(rate_hz=rate_hz(t_imu_a[sel], imu_topic_), axes_known=False)
            assumptions["R_cam_imu"] = (
                "UNKNOWN (axes_known: false): identity as a placeholder; calibrate's axis "
                "search decides from the images (or give --calib)"
            )
        meta = SessionMeta(
            camera=camera,
            imu=imu,
            target_kind="natural",
            extra={
                "import": {
                    "source": "rosbag",
                    "path": str(src),
                    "topics": {"image": img_topic, "imu": imu_topic_},
                    "assumptions": assumptions,
                }
            },
        )
        dropped, n, prev = 0, 0, None
        with SessionWriter(out, meta) as wr:
            for stamp_ns, img in itertools.chain([first], frames):
                if n >= limit:
                    break
                if img.shape[:2] != (h, w_px):
                    raise ImportFormatError(f"rosbag: {img_topic} changes size mid-stream")
                t0 = frame_start_ns(stamp_ns, stamp, exp, readout)
                if prev is not None and t0 <= prev:
                    dropped += 1
                    continue
                wr.add_frame(t0, img, exp)
                prev, n = t0, n + 1
            wr.add_imu(t_imu_a[sel], w[sel], a[sel] if has_acc else None)
    except BlurTrackError:
        raise
    except (KeyError, AttributeError, ValueError, TypeError) as exc:
        raise ImportFormatError(f"rosbag: {src}: malformed message ({exc})") from None
    finally:
        reader.close()
    return {
        "frames": n,
        "frames_dropped_out_of_order": dropped,
        "gyro_samples": int(sel.size),
        "resolution": [w_px, h],
        "topics": {"image": img_topic, "imu": imu_topic_},
        "assumptions": assumptions,
    }
