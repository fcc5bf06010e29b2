"""JSON schemas and message encoders of the recorder log (``blurtrack-reclog/2``).

Every channel is JSON with a registered ``jsonschema`` whose properties are declared, so
Foxglove and any MCAP reader can decode, plot and validate it:

- ``/cam0``: ``foxglove.RawImage`` (``mono8``, ``mono16``, ``bgr8``, ``bgra8``; little-endian)
  or ``foxglove.CompressedImage`` (``png``, lossless), the field layout of Foxglove's published
  JSON schemas (bytes as base64, ``contentEncoding: base64``); Foxglove's Image panel shows it.
- ``/cam0/info``: ``blurtrack.FrameInfo``, written just before each image: index, camera
  timestamp and exposure (ns), host arrival time, stamp source.
- ``/imu``: ``blurtrack.ImuSample``, ONE message per sample, ``timestamp`` = the sample's device
  time, ``gyro_radps``/``accel_mps2`` as ``{x, y, z}`` (Foxglove plots ``/imu.gyro_radps.x``).
- ``/stats``: ``blurtrack.RecorderStats``; ``/events``: ``foxglove.Log`` (Foxglove's Log panel).
"""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}
_B64 = {"type": "string", "contentEncoding": "base64"}
_XYZ = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in "xyz"},
    "required": ["x", "y", "z"],
}
_INT = {"type": "integer"}
_UINT = {"type": "integer", "minimum": 0}

RAW_IMAGE = {
    "title": "foxglove.RawImage",
    "description": "A raw image (Foxglove schema)",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "width": _UINT,
        "height": _UINT,
        "encoding": {"type": "string"},
        "step": _UINT,
        "data": _B64,
    },
    "required": ["timestamp", "frame_id", "width", "height", "encoding", "step", "data"],
}
COMPRESSED_IMAGE = {
    "title": "foxglove.CompressedImage",
    "description": "A compressed image (Foxglove schema)",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "data": _B64,
        "format": {"type": "string"},
    },
    "required": ["timestamp", "frame_id", "data", "format"],
}
FRAME_INFO = {
    "title": "blurtrack.FrameInfo",
    "description": "Camera frame bookkeeping; the image follows on /cam0",
    "type": "object",
    "properties": {
        "index": _UINT,
        "timestamp_ns": {**_INT, "description": "start of the top row's exposure, host clock"},
        "exposure_ns": {**_INT, "description": "exposure; <= 0 when the camera did not say"},
        "host_ns": {**_INT, "description": "host time of arrival"},
        "stamp_source": {"enum": ["host", "driver"]},
    },
    "required": ["index", "timestamp_ns", "exposure_ns", "host_ns", "stamp_source"],
}
IMU_SAMPLE = {
    "title": "blurtrack.ImuSample",
    "description": "One IMU sample; timestamp is the device time",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "index": _INT,
        "t_dev_us": {**_INT, "description": "device time, microseconds"},
        "host_ns": {**_INT, "description": "host time of arrival, ns"},
        "gyro_radps": {**_XYZ, "description": "angular velocity, IMU frame, rad/s"},
        "accel_mps2": {"oneOf": [_XYZ, {"type": "null"}], "description": "m/s^2 or null"},
    },
    "required": ["timestamp", "index", "t_dev_us", "host_ns", "gyro_radps", "accel_mps2"],
}
STATS = {
    "title": "blurtrack.RecorderStats",
    "description": "Recorder and driver counters at a flush",
    "type": "object",
    "properties": {
        "imu_samples": _UINT,
        "frames": _UINT,
        "camera_dropped": _UINT,
        "imu": {
            "type": "object",
            "description": "IMU driver counters (crc_errors, dropped, resyncs, ...)",
            "additionalProperties": {"type": ["number", "integer", "string", "boolean", "null"]},
        },
    },
    "required": ["imu_samples", "frames"],
}
LOG = {
    "title": "foxglove.Log",
    "description": "A log message (Foxglove schema)",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {"enum": [0, 1, 2, 3, 4, 5], "description": "2 info, 3 warning, 4 error"},
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": _UINT,
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}
#: topic -> schema
CHANNELS: dict[str, dict[str, Any]] = {
    "/cam0/info": FRAME_INFO,
    "/imu": IMU_SAMPLE,
    "/stats": STATS,
    "/events": LOG,
}
LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
LEVEL_NAMES = {v: k for k, v in LEVELS.items()}
#: Raw encodings written: (channels, bytes per channel) -> Foxglove encoding.
RAW_ENCODINGS = {(1, 1): "mono8", (1, 2): "mono16", (3, 1): "bgr8", (4, 1): "bgra8"}
RAW_LAYOUT = {v: k for k, v in RAW_ENCODINGS.items()}


def time_of(t_ns: int) -> dict[str, int]:
    """Foxglove ``time`` of a nanosecond stamp (negative stamps clamp to 0)."""
    t = max(int(t_ns), 0)
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def dumps(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()


def xyz(v: np.ndarray) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def image_message(
    t_ns: int, data: bytes, encoding: str, shape: tuple[int, ...], itemsize: int
) -> tuple[dict[str, Any], bytes]:
    """``(schema, payload)`` of a frame: PNG bytes as CompressedImage, raw pixels as RawImage.

    The base64 text is spliced into the JSON as bytes (it needs no escaping), which saves a
    scan and a copy of every megabyte-sized frame on the recorder's writer thread."""
    head: dict[str, Any]
    if encoding == "png":
        schema, head = COMPRESSED_IMAGE, {"timestamp": time_of(t_ns), "frame_id": "cam0"}
        head["format"] = "png"
    else:
        h, w = shape[:2]
        c = 1 if len(shape) == 2 else shape[2]
        schema = RAW_IMAGE
        head = {
            "timestamp": time_of(t_ns),
            "frame_id": "cam0",
            "width": int(w),
            "height": int(h),
            "encoding": RAW_ENCODINGS[(c, itemsize)],
            "step": int(w * c * itemsize),
        }
    return schema, b"".join((dumps(head)[:-1], b',"data":"', base64.b64encode(data), b'"}'))
