"""The recorder's crash-safe log: an MCAP file with small chunks, readable when truncated.

The recorder closes a chunk and hands it to the operating system every ``flush_interval_s``
(0.25 s by default), so a recorder killed with SIGKILL loses at most the chunk it was filling.
:func:`scan_log` and :func:`iter_frames` read a log record by record and stop, saying why, at the
first record that is cut off or fails its CRC; :func:`recover_log` rewrites what survived into a
complete, indexed MCAP file.

Channels (message log time = host time of arrival, ns):
- ``/imu``: JSON ``{"index", "t_dev_us", "host_ns", "gyro_radps", "accel_mps2"}`` per read.
- ``/cam0``: ``blurtrack-frame/1``: a little-endian header ``<qqqqBBHHBB`` (index,
  timestamp_ns, exposure_ns, host_ns, stamp source 0 host / 1 driver, encoding 0 PNG / 1 raw,
  height, width, channels, bytes per channel) followed by the PNG bytes or the raw C-order
  pixels (raw is the default: PNG-encoding 1280 x 720 noisy frames costs ~60 ms each, more
  than a frame period, so the recorder stores pixels and the conversion encodes offline).
- ``/stats``: JSON snapshots of driver counters; ``/events``: JSON ``{"level", "message"}``.
The metadata record ``recording`` (string map) describes the rig; ``format`` must be
``blurtrack-reclog/1``.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rigs.camera_types import CameraFrame
from rigs.errors import RecorderLogError

LOG_FORMAT = "blurtrack-reclog/1"
FRAME_HEADER = struct.Struct("<qqqqBBHHBB")
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
_JSON_SCHEMA = {
    "/imu": {"type": "object", "title": "blurtrack.ImuBatch"},
    "/stats": {"type": "object", "title": "blurtrack.Stats"},
    "/events": {"type": "object", "title": "blurtrack.Event"},
}


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
        for topic, schema in _JSON_SCHEMA.items():
            sid = self._w.register_schema(
                schema["title"], "jsonschema", json.dumps(schema).encode()
            )
            self._channels[topic] = self._w.register_channel(topic, "json", sid)
        fsid = self._w.register_schema("blurtrack.Frame", "", b"")
        self._channels["/cam0"] = self._w.register_channel("/cam0", "blurtrack-frame/1", fsid)
        self._w.add_metadata("recording", {"format": LOG_FORMAT, **metadata})
        self._seq = 0
        self._final_size = 0
        self.flush()

    def write_message(self, topic: str, t_ns: int, data: bytes) -> None:
        """Append an already encoded message to one of the log's channels (used by recover)."""
        if topic not in self._channels:
            raise RecorderLogError(f"unknown log channel {topic!r}")
        self._add(topic, t_ns, data)

    def _add(self, topic: str, t_ns: int, data: bytes) -> None:
        self._seq += 1
        self._w.add_message(
            self._channels[topic], log_time=t_ns, data=data, publish_time=t_ns, sequence=self._seq
        )

    def _json(self, topic: str, t_ns: int, obj: dict[str, Any]) -> None:
        self._add(topic, t_ns, json.dumps(obj, allow_nan=False).encode())

    def write_imu(
        self,
        t_ns: int,
        index: np.ndarray,
        t_dev_us: np.ndarray,
        host_ns: np.ndarray,
        gyro_radps: np.ndarray,
        accel_mps2: np.ndarray | None,
    ) -> None:
        accel = None
        if accel_mps2 is not None and np.all(np.isfinite(accel_mps2)):
            accel = accel_mps2.tolist()
        self._json(
            "/imu",
            t_ns,
            {
                "index": index.tolist(),
                "t_dev_us": t_dev_us.tolist(),
                "host_ns": host_ns.tolist(),
                "gyro_radps": gyro_radps.tolist(),
                "accel_mps2": accel,
            },
        )

    def write_frame(self, frame: CameraFrame, data: bytes, encoding: str = "raw") -> None:
        """Log a frame; ``data`` is the PNG file (``png``) or ``frame.image.tobytes()``."""
        img = frame.image
        h, w = img.shape[:2]
        channels = 1 if img.ndim == 2 else img.shape[2]
        header = FRAME_HEADER.pack(
            frame.index,
            frame.timestamp_ns,
            frame.exposure_ns,
            frame.host_ns,
            1 if frame.stamp_source == "driver" else 0,
            ENCODINGS[encoding],
            h,
            w,
            channels,
            img.dtype.itemsize,
        )
        self._add("/cam0", frame.host_ns, header + data)

    def write_stats(self, t_ns: int, stats: dict[str, Any]) -> None:
        self._json("/stats", t_ns, stats)

    def write_event(self, t_ns: int, level: str, message: str) -> None:
        self._json("/events", t_ns, {"level": level, "message": message})

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


def _walk(path: Path) -> Iterator[tuple[str, Any]]:
    """Messages as (topic, Message), then ("", reason); validates the format."""
    path = Path(path)
    topics: dict[int, str] = {}
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
                    f"{path}: unsupported log format {rec.metadata.get('format')!r}"
                )
            seen_meta = True
            yield "meta", rec
        elif isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Message) and rec.channel_id in topics:
            yield topics[rec.channel_id], rec


def scan_log(path: str | Path) -> LogScan:
    """Read a (possibly truncated) log; raise RecorderLogError if it is not one at all."""
    meta: dict[str, str] = {}
    cols: dict[str, list[Any]] = {k: [] for k in ("index", "t_dev_us", "host_ns", "gyro", "acc")}
    frame_ts: list[int] = []
    frame_exp: list[int] = []
    stats: list[dict[str, Any]] = []
    events: list[dict[str, Any]] = []
    damage, n = "", 0
    for topic, rec in _walk(Path(path)):
        if topic == "":
            damage = rec
            break
        if topic == "meta":
            meta = dict(rec.metadata)
            continue
        n += 1
        if topic == "/imu":
            obj = json.loads(rec.data)
            cols["index"] += obj["index"]
            cols["t_dev_us"] += obj["t_dev_us"]
            cols["host_ns"] += obj["host_ns"]
            cols["gyro"] += obj["gyro_radps"]
            k = len(obj["index"])
            cols["acc"] += obj["accel_mps2"] or [[np.nan] * 3] * k
        elif topic == "/cam0":
            _, ts, exp, *_ = FRAME_HEADER.unpack_from(rec.data)
            frame_ts.append(ts)
            frame_exp.append(exp)
        elif topic == "/stats":
            stats.append(json.loads(rec.data))
        elif topic == "/events":
            events.append(json.loads(rec.data))
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


def iter_frames(path: str | Path) -> Iterator[FrameRecord]:
    """The logged frames in order, up to the first damaged record."""
    for topic, rec in _walk(Path(path)):
        if topic == "/cam0":
            index, ts, exp, host, src, enc, h, w, c, size = FRAME_HEADER.unpack_from(rec.data)
            yield FrameRecord(
                index,
                ts,
                exp,
                host,
                "driver" if src else "host",
                enc,
                (h, w, c),
                size,
                bytes(rec.data[FRAME_HEADER.size :]),
            )


@dataclass(frozen=True)
class RecoverResult:
    """What :func:`recover_log` kept."""

    out_path: Path
    messages: int
    imu_samples: int
    frames: int
    was_complete: bool
    damage: str


def recover_log(path: str | Path, out_path: str | Path) -> RecoverResult:
    """Copy every intact message of ``path`` into a new, finished log at ``out_path``."""
    path, out_path = Path(path), Path(out_path)
    if out_path.resolve() == path.resolve():
        raise RecorderLogError("the recovered log must not overwrite the damaged one")
    scan_meta: dict[str, str] = {}
    writer: RecLogWriter | None = None
    damage, n, imu_n, frames = "", 0, 0, 0
    for topic, rec in _walk(path):
        if topic == "meta":
            scan_meta = {k: v for k, v in rec.metadata.items() if k != "format"}
            writer = RecLogWriter(out_path, scan_meta)
            continue
        if topic == "":
            damage = rec
            break
        assert writer is not None  # the metadata record comes first in our logs
        writer.write_message(topic, rec.log_time, rec.data)
        n += 1
        if topic == "/imu":
            imu_n += len(json.loads(rec.data)["index"])
        elif topic == "/cam0":
            frames += 1
    if writer is None:
        raise RecorderLogError(f"{path} holds no recording metadata")
    writer.write_event(0, "info", f"recovered from {path.name}: " + (damage or "log was complete"))
    writer.finish()
    return RecoverResult(out_path, n, imu_n, frames, not damage, damage)
