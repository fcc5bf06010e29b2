"""The recorder's crash-safe log: an MCAP file with small chunks, readable when truncated.

The recorder closes a chunk and hands it to the OS every ``flush_interval_s`` (0.25 s by
default), so a recorder killed with SIGKILL loses at most the chunk it was filling. :func:`scan_log`
and :func:`iter_frames` read record by record and stop, saying why, at the first record that is
cut off or fails its CRC; :func:`recover_log` rewrites what survived into a complete MCAP file.

Channels (``rigs/reclog_schema.py``; every one JSON with a declared ``jsonschema``, so
Foxglove shows and plots them; message log time = host time, ns):
- ``/cam0``: ``foxglove.RawImage`` (raw pixels, the default: PNG-encoding 1280 x 720 noisy
  frames costs ~60 ms each, more than a frame period) or ``foxglove.CompressedImage`` (PNG),
  each preceded by its ``/cam0/info`` (``blurtrack.FrameInfo``: index, timestamp, exposure, host
  time, stamp source); a frame counts only once both are in the log.
- ``/imu``: ``blurtrack.ImuSample``, one message per sample, stamped with its device time
  (``timestamp``, ``publish_time``) and logged at its own host arrival time.
- ``/stats``: ``blurtrack.RecorderStats``; ``/events``: ``foxglove.Log``.
The metadata record ``recording`` (string map) describes the rig; ``format`` must be
``blurtrack-reclog/2`` (version 1 logs, with binary frames, are refused).
"""

from __future__ import annotations

import base64
import json
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rigs import reclog_schema as sch
from rigs.camera_types import CameraFrame
from rigs.errors import RecorderLogError

LOG_FORMAT = "blurtrack-reclog/2"
ENCODINGS = {"png": 0, "raw": 1}
MAX_FRAME_PIXELS = 1 << 26  # refuse absurd sizes from a damaged header before allocating
_READ_ERRORS = (
    McapError,
    ValueError,
    struct.error,
    EOFError,
    UnicodeDecodeError,
    KeyError,
    IndexError,
)
_IMAGE_KEYS = {"foxglove.CompressedImage": "/cam0:png", "foxglove.RawImage": "/cam0:raw"}


class RecLogWriter:
    """Append-only writer. ``flush()`` closes the current chunk and pushes it to the OS."""

    def __init__(self, path: str | Path, metadata: dict[str, str]) -> None:
        self.path = Path(path)
        if not hasattr(Writer, "flush"):  # added in mcap 1.6; the crash-loss bound needs it
            raise RecorderLogError("the recorder needs mcap >= 1.6 (Writer.flush)")
        try:
            # held open for the whole recording; closed in finish(). "x": never overwrite
            self._file = open(self.path, "xb")  # noqa: SIM115
        except FileExistsError:
            raise RecorderLogError(f"{self.path} already exists; choose another log path") from None
        except OSError as exc:
            raise RecorderLogError(f"cannot create log {self.path}: {exc.strerror}") from None
        # frames are raw or PNG and IMU batches are small: compression would only cost CPU
        self._w = Writer(self._file, chunk_size=4 << 20, compression=CompressionType.NONE)
        self._w.start(profile="", library="blurtrack-rigs")
        self._channels: dict[str, int] = {}
        for topic, schema in sch.CHANNELS.items():
            self._register(topic, topic, schema)
        self._w.add_metadata("recording", {"format": LOG_FORMAT, **metadata})
        self._seq = 0
        self._final_size = 0
        self.flush()

    def _register(self, key: str, topic: str, schema: dict[str, Any]) -> None:
        sid = self._w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
        self._channels[key] = self._w.register_channel(topic, "json", sid)

    def write_message(
        self, key: str, t_ns: int, data: bytes, publish_ns: int | None = None
    ) -> None:
        """Append an already encoded message (used by recover); ``key`` is a topic or, for
        images, ``/cam0:raw`` / ``/cam0:png``."""
        if key in _IMAGE_KEYS.values() and key not in self._channels:
            raw = key == "/cam0:raw"
            self._register(key, "/cam0", sch.RAW_IMAGE if raw else sch.COMPRESSED_IMAGE)
        if key not in self._channels:
            raise RecorderLogError(f"unknown log channel {key!r}")
        self._add(key, t_ns, data, publish_ns)

    def _add(self, key: str, t_ns: int, data: bytes, publish_ns: int | None = None) -> None:
        self._seq += 1
        self._w.add_message(
            self._channels[key],
            log_time=int(t_ns),
            data=data,
            publish_time=int(t_ns if publish_ns is None else publish_ns),
            sequence=self._seq,
        )

    def _json(self, topic: str, t_ns: int, obj: dict[str, Any], publish_ns: int | None = None):
        self._add(topic, t_ns, sch.dumps(obj), publish_ns)

    def write_imu(
        self,
        t_ns: int,
        index: np.ndarray,
        t_dev_us: np.ndarray,
        host_ns: np.ndarray,
        gyro_radps: np.ndarray,
        accel_mps2: np.ndarray | None,
    ) -> None:
        """One ``/imu`` message per sample (``t_ns``, the batch's arrival, is not needed: each
        sample is logged at its own host time and stamped with its device time)."""
        acc = None
        if accel_mps2 is not None and np.all(np.isfinite(accel_mps2)):
            acc = np.asarray(accel_mps2, float)
        for k in range(len(index)):
            dev_ns = int(t_dev_us[k]) * 1000
            msg = {
                "timestamp": sch.time_of(dev_ns),
                "index": int(index[k]),
                "t_dev_us": int(t_dev_us[k]),
                "host_ns": int(host_ns[k]),
                "gyro_radps": sch.xyz(gyro_radps[k]),
                "accel_mps2": None if acc is None else sch.xyz(acc[k]),
            }
            self._json("/imu", int(host_ns[k]), msg, publish_ns=dev_ns)

    def write_frame(self, frame: CameraFrame, data: bytes, encoding: str = "raw") -> None:
        """Log a frame; ``data`` is the PNG file (``png``) or ``frame.image.tobytes()``."""
        img = frame.image
        channels = 1 if img.ndim == 2 else img.shape[2]
        if encoding == "raw" and (channels, img.dtype.itemsize) not in sch.RAW_ENCODINGS:
            import cv2  # no Foxglove raw encoding for this layout (16-bit colour): PNG, lossless

            ok, buf = cv2.imencode(".png", img)
            if not ok:
                raise RecorderLogError(f"cannot PNG-encode frame {frame.index}")
            data, encoding = buf.tobytes(), "png"
        info = {
            "index": int(frame.index),
            "timestamp_ns": int(frame.timestamp_ns),
            "exposure_ns": int(frame.exposure_ns),
            "host_ns": int(frame.host_ns),
            "stamp_source": "driver" if frame.stamp_source == "driver" else "host",
        }
        self._json("/cam0/info", frame.host_ns, info, publish_ns=frame.timestamp_ns)
        _, payload = sch.image_message(
            frame.timestamp_ns, data, encoding, img.shape, img.dtype.itemsize
        )
        self.write_message(f"/cam0:{encoding}", frame.host_ns, payload, frame.timestamp_ns)

    def write_stats(self, t_ns: int, stats: dict[str, Any]) -> None:
        self._json("/stats", t_ns, stats)

    def write_event(self, t_ns: int, level: str, message: str) -> None:
        msg = {
            "timestamp": sch.time_of(t_ns),
            "level": sch.LEVELS.get(level, 0),
            "message": message,
            "name": "blurtrack-recorder",
            "file": "",
            "line": 0,
        }
        self._json("/events", t_ns, msg)

    def flush(self) -> None:
        self._w.flush()

    @property
    def bytes_written(self) -> int:
        return self._final_size if self._file.closed else self._file.tell()

    def finish(self) -> None:
        self._w.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._final_size = self._file.tell()
        self._file.close()


@dataclass
class FrameRecord:
    """A frame as logged; :meth:`image` decodes it."""

    index: int
    timestamp_ns: int
    exposure_ns: int
    host_ns: int
    stamp_source: str
    encoding: int
    shape: tuple[int, int, int]  # height, width, channels
    itemsize: int
    data: bytes

    def image(self) -> np.ndarray:
        """(H, W) or (H, W, C) uint8/uint16; RecorderLogError if the bytes do not fit."""
        h, w, c = self.shape
        if self.encoding == ENCODINGS["png"]:
            from blurtrack.io.images import ImageError, decode_image

            try:
                return decode_image(
                    self.data, max_pixels=MAX_FRAME_PIXELS, what=f"frame {self.index}"
                )
            except ImageError as exc:
                raise RecorderLogError(str(exc)) from None
        if self.encoding != ENCODINGS["raw"] or self.itemsize not in (1, 2):
            raise RecorderLogError(f"frame {self.index} has an unknown encoding")
        if h * w * c > MAX_FRAME_PIXELS or len(self.data) != h * w * c * self.itemsize:
            raise RecorderLogError(
                f"frame {self.index}: {len(self.data)} bytes do not make a {w}x{h}x{c} image"
            )
        dtype = np.uint8 if self.itemsize == 1 else np.dtype("<u2")
        img = np.frombuffer(self.data, dtype=dtype).reshape((h, w, c) if c > 1 else (h, w))
        return img.astype(np.uint16) if self.itemsize == 2 else img


@dataclass
class LogScan:
    """Everything in a log except the images (see :func:`iter_frames`)."""

    metadata: dict[str, str]
    imu_index: np.ndarray
    imu_t_dev_us: np.ndarray
    imu_host_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray | None
    frame_timestamps_ns: np.ndarray
    frame_exposures_ns: np.ndarray
    stats: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    complete: bool = True
    damage: str = ""  # why reading stopped early, empty for a complete log
    messages: int = 0

    @property
    def last_stats(self) -> dict[str, Any]:
        return self.stats[-1] if self.stats else {}


def _records(path: Path) -> Iterator[tuple[str, Any]]:
    """Yield ("record", rec) ... then ("end", reason) with reason "" for a complete file."""
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed by the with-block below
    except OSError as exc:
        raise RecorderLogError(f"cannot open log {path}: {exc.strerror}") from None
    with f:
        reader = StreamReader(f, validate_crcs=True, record_size_limit=1 << 30)
        try:
            for rec in reader.records:
                yield "record", rec
        except _READ_ERRORS as exc:
            yield (
                "end",
                f"log ends in a damaged or cut-off record near byte {f.tell()} "
                f"({type(exc).__name__}: {exc})",
            )
            return
    yield "end", ""


def walk_log(path: Path) -> Iterator[tuple[str, Any]]:
    """Messages as (key, Message), then ("", reason); validates the format. The key is the
    topic, or ``/cam0:raw`` / ``/cam0:png`` for images (by their channel's schema)."""
    path = Path(path)
    schemas: dict[int, str] = {}
    keys: dict[int, str] = {}
    seen_meta = False
    for kind, rec in _records(path):
        if kind == "end":
            if not seen_meta:
                raise RecorderLogError(
                    f"{path} is not a BlurTrack recorder log (no '{LOG_FORMAT}' metadata)"
                    + (f"; {rec}" if rec else "")
                )
            yield "", rec
            return
        if isinstance(rec, Metadata) and rec.name == "recording":
            if rec.metadata.get("format") != LOG_FORMAT:
                raise RecorderLogError(
                    f"{path}: unsupported log format {rec.metadata.get('format')!r} "
                    f"(this version reads {LOG_FORMAT!r})"
                )
            seen_meta = True
            yield "meta", rec
        elif isinstance(rec, Schema):
            schemas[rec.id] = rec.name
        elif isinstance(rec, Channel):
            name = schemas.get(rec.schema_id, "")
            keys[rec.id] = _IMAGE_KEYS.get(name, rec.topic) if rec.topic == "/cam0" else rec.topic
        elif isinstance(rec, Message) and rec.channel_id in keys:
            yield keys[rec.channel_id], rec


def _paired(path: Path) -> Iterator[tuple[str, Any, dict[str, Any] | None]]:
    """:func:`walk_log` with each image paired with the ``/cam0/info`` just before it (an info whose
    image never came, cut off by a crash, is dropped); other messages pass with None."""
    info: dict[str, Any] | None = None
    for key, rec in walk_log(path):
        if key == "/cam0/info":
            try:
                info = json.loads(rec.data)
                if not set(sch.FRAME_INFO["required"]) <= set(info):
                    raise ValueError("missing keys")
            except (ValueError, TypeError):
                raise RecorderLogError(f"{path}: malformed /cam0/info message") from None
            continue
        if key.startswith("/cam0:"):
            if info is not None:
                yield key, rec, info
            info = None
            continue
        yield key, rec, None


def _scan_items(path: Path) -> Iterator[tuple[str, Any, dict[str, Any] | None, Any]]:
    """``_paired`` with the JSON of IMU, stats and event messages parsed (images are not)."""
    for key, rec, info in _paired(path):
        try:
            obj = json.loads(rec.data) if key in ("/imu", "/stats", "/events") else None
        except ValueError as exc:
            raise RecorderLogError(f"{path}: malformed {key} message ({exc})") from None
        yield key, rec, info, obj


def scan_log(path: str | Path) -> LogScan:
    """Read a (possibly truncated) log; raise RecorderLogError if it is not one at all."""
    meta: dict[str, str] = {}
    cols: dict[str, list[Any]] = {k: [] for k in ("index", "t_dev_us", "host_ns", "gyro", "acc")}
    frame_ts: list[int] = []
    frame_exp: list[int] = []
    stats: list[dict[str, Any]] = []
    events: list[dict[str, Any]] = []
    damage, n = "", 0
    nan3 = [np.nan] * 3
    for key, rec, info, obj in _scan_items(Path(path)):
        if key == "":
            damage = rec
            break
        if key == "meta":
            meta = dict(rec.metadata)
            continue
        n += 1
        if key == "/imu":
            try:
                g, a = obj["gyro_radps"], obj["accel_mps2"]
                row: tuple[Any, ...] = (
                    obj["index"],
                    obj["t_dev_us"],
                    obj["host_ns"],
                    [g["x"], g["y"], g["z"]],
                )
                row += (nan3 if a is None else [a["x"], a["y"], a["z"]],)
            except (KeyError, TypeError) as exc:
                raise RecorderLogError(f"{path}: malformed /imu message ({exc})") from None
            for col, v in zip(("index", "t_dev_us", "host_ns", "gyro", "acc"), row, strict=True):
                cols[col].append(v)
        elif info is not None:
            frame_ts.append(int(info["timestamp_ns"]))
            frame_exp.append(int(info["exposure_ns"]))
        elif key == "/stats":
            stats.append(obj)
        elif key == "/events":
            level = sch.LEVEL_NAMES.get(obj.get("level"), "unknown")
            events.append({"level": level, "message": obj.get("message", "")})
    m = len(cols["index"])
    acc = np.asarray(cols["acc"], dtype=np.float64).reshape(m, 3)
    return LogScan(
        metadata=meta,
        imu_index=np.asarray(cols["index"], dtype=np.int64),
        imu_t_dev_us=np.asarray(cols["t_dev_us"], dtype=np.int64),
        imu_host_ns=np.asarray(cols["host_ns"], dtype=np.int64),
        gyro_radps=np.asarray(cols["gyro"], dtype=np.float64).reshape(m, 3),
        accel_mps2=None if m == 0 or np.isnan(acc).any() else acc,
        frame_timestamps_ns=np.asarray(frame_ts, dtype=np.int64),
        frame_exposures_ns=np.asarray(frame_exp, dtype=np.int64),
        stats=stats,
        events=events,
        complete=not damage,
        damage=damage,
        messages=n,
    )


def _frame_record(key: str, rec: Any, info: dict[str, Any]) -> FrameRecord:
    img = json.loads(rec.data)
    data = base64.b64decode(img["data"], validate=True)
    src = "driver" if info.get("stamp_source") == "driver" else "host"
    head = (int(info["index"]), int(info["timestamp_ns"]), int(info["exposure_ns"]))
    if key == "/cam0:png":
        return FrameRecord(*head, int(info["host_ns"]), src, ENCODINGS["png"], (0, 0, 0), 1, data)
    if img["encoding"] not in sch.RAW_LAYOUT:
        raise RecorderLogError(f"frame {head[0]}: unknown raw encoding {img['encoding']!r}")
    c, itemsize = sch.RAW_LAYOUT[img["encoding"]]
    shape = (int(img["height"]), int(img["width"]), c)
    return FrameRecord(*head, int(info["host_ns"]), src, ENCODINGS["raw"], shape, itemsize, data)


def iter_frames(path: str | Path) -> Iterator[FrameRecord]:
    """The logged frames in order, up to the first damaged record."""
    for key, rec, info in _paired(Path(path)):
        if info is not None:
            try:
                yield _frame_record(key, rec, info)
            except (KeyError, ValueError, TypeError) as exc:
                raise RecorderLogError(f"{path}: malformed frame message ({exc})") from None
