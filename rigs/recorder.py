"""The recorder: IMU and camera threads feeding one writer that flushes small chunks.

One thread per device reads and timestamps; the camera thread also serialises frames (raw
pixels by default, or PNG, during which OpenCV releases the GIL), with at most ``frame_queue``
frames waiting for the writer. The calling thread writes everything into the log in arrival
order and closes a chunk every ``flush_interval_s``, so a killed recorder loses at most that
much. A status snapshot (rates, drops, CRC errors, what is safely on disk) goes to ``on_status``
every ``status_interval_s``. The recording ends on :meth:`Recorder.stop` (Ctrl-C), after
``duration_s``, when the camera stream ends (plus ``after_camera_end_s`` of IMU), or when a
device disconnects; in every case what the devices delivered is written and the log is finished
properly before :meth:`Recorder.run` returns.
"""

from __future__ import annotations

import errno
import queue
import threading
from collections import deque
from collections.abc import Callable
from contextlib import suppress
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigs.camera_types import CameraFrame, CameraSource, image_info
from rigs.clock import Clock, MonotonicClock
from rigs.errors import DeviceDisconnectedError, RigConfigError, RigError
from rigs.imu import ImuBatch, ImuSource
from rigs.reclog import RecLogWriter


@dataclass(frozen=True)
class RecorderConfig:
    """Timing of flushes and status lines, optional duration, how frames are stored (``raw``
    pixels, the default, or ``png``: ~60 ms per noisy 1280 x 720 frame, too slow for 30 fps on
    one core), PNG effort, frame queue depth, and whether the end of a camera stream (a
    replayed file) ends the recording."""

    flush_interval_s: float = 0.25
    status_interval_s: float = 0.5
    duration_s: float | None = None
    frame_encoding: str = "raw"
    png_compression: int = 1
    frame_queue: int = 8
    stop_when_camera_ends: bool = True
    after_camera_end_s: float = 0.3  # IMU keeps recording this long after the last frame
    # (a virtual board with a sample limit is instead recorded to its last sample)
    imu_tail_timeout_s: float = 2.0  # wall clock beyond that tail before a lagging IMU is
    # given up on (its tail is then short, and the log says so)

    def __post_init__(self) -> None:
        if not 0.01 <= self.flush_interval_s <= 1.0:
            raise RigConfigError("flush_interval_s must be in [0.01, 1] (crash loss bound)")
        if self.after_camera_end_s < 0 or self.imu_tail_timeout_s < 0:
            raise RigConfigError("after_camera_end_s and imu_tail_timeout_s must be non-negative")
        if self.status_interval_s <= 0 or (self.duration_s is not None and self.duration_s <= 0):
            raise RigConfigError("status_interval_s and duration_s must be positive")
        if self.frame_encoding not in ("raw", "png"):
            raise RigConfigError("frame_encoding must be raw or png")
        if not 0 <= self.png_compression <= 9 or self.frame_queue < 1:
            raise RigConfigError("png_compression must be 0..9 and frame_queue >= 1")


@dataclass
class RecorderStatus:
    """A live snapshot; ``flushed_*`` counts are on disk (survive SIGKILL)."""

    elapsed_s: float = 0.0
    imu_samples: int = 0
    imu_rate_hz: float = 0.0
    frames: int = 0
    fps: float = 0.0
    imu_crc_errors: int = 0
    imu_dropped: int = 0
    imu_discarded: int = 0  # duplicates, bad counters and time jumps back (see rigs.sequence)
    imu_resyncs: int = 0
    camera_dropped: int = 0
    flushed_imu_samples: int = 0
    flushed_frames: int = 0
    log_bytes: int = 0

    def line(self) -> str:
        return (
            f"{self.elapsed_s:7.1f} s  imu {self.imu_samples} ({self.imu_rate_hz:.0f} Hz, "
            f"dropped {self.imu_dropped}, discarded {self.imu_discarded}, crc "
            f"{self.imu_crc_errors}, resync "
            f"{self.imu_resyncs})  cam {self.frames} ({self.fps:.1f} fps, dropped "
            f"{self.camera_dropped})  flushed imu {self.flushed_imu_samples} frames "
            f"{self.flushed_frames}  {self.log_bytes / 1e6:.1f} MB"
        )


@dataclass
class RecordResult:
    """How a recording ended."""

    log_path: Path
    status: RecorderStatus
    imu_stats: dict[str, int] = field(default_factory=dict)
    stopped_by: str = ""  # "stop", "duration", "camera-ended", "error"
    error: str | None = None
    warnings: list[str] = field(default_factory=list)  # e.g. an IMU tail cut short

    def as_dict(self) -> dict[str, Any]:
        return {
            "log": str(self.log_path),
            "status": asdict(self.status),
            "imu_stats": self.imu_stats,
            "stopped_by": self.stopped_by,
            "warnings": list(self.warnings),
            "error": self.error,
        }


class ImuProgress:
    """How far the IMU's samples reach, in device time, and where a host instant falls on
    the device clock.

    A sample's host time is its device time plus the (unknown, fixed) clock offset plus a
    latency >= 0, so ``host - device`` at the fastest delivery bounds the offset from above;
    its minimum over the last ``window_ns`` of batches (a short window: the two crystals drift
    apart by up to ~1e-4) maps a host instant to a device time no earlier than the true one.
    The recorder waits for samples that far, not for wall-clock time: a starved reader
    delivers a backlog late, and the backlog is what covers the last exposure.
    """

    def __init__(self, window_ns: int = 2_000_000_000) -> None:
        self.window_ns = window_ns
        self.last_dev_ns: int | None = None
        self._offsets: deque[tuple[int, int]] = deque()  # (host_ns, host - device ns)

    def add(self, batch: ImuBatch) -> None:
        """Account one batch (its last sample is the freshest of its read)."""
        if len(batch) == 0:
            return
        host_ns, dev_ns = int(batch.host_ns[-1]), int(batch.t_dev_us[-1]) * 1000
        self.last_dev_ns = dev_ns if self.last_dev_ns is None else max(self.last_dev_ns, dev_ns)
        self._offsets.append((host_ns, host_ns - dev_ns))
        while self._offsets[0][0] < host_ns - self.window_ns:
            self._offsets.popleft()

    def device_ns_of(self, host_ns: int) -> int | None:
        """The device time of host instant ``host_ns`` (an upper bound), None before any sample."""
        if not self._offsets:
            return None
        return host_ns - min(off for _, off in self._offsets)

    def reaches(self, host_ns: int) -> bool:
        """Has a sample taken at or after host instant ``host_ns`` arrived?"""
        target = self.device_ns_of(host_ns)
        return target is not None and self.last_dev_ns is not None and self.last_dev_ns >= target


class Recorder:
    """Record ``imu`` and/or ``camera`` into ``log_path`` (see module docstring)."""

    def __init__(
        self,
        log_path: str | Path,
        imu: ImuSource | None,
        camera: CameraSource | None,
        metadata: dict[str, str] | None = None,
        config: RecorderConfig | None = None,
        clock: Clock | None = None,
        on_status: Callable[[RecorderStatus], None] | None = None,
    ) -> None:
        if imu is None and camera is None:
            raise RigError("nothing to record: give an IMU, a camera or both")
        self.log_path = Path(log_path)
        self.imu, self.camera = imu, camera
        self.metadata = dict(metadata or {})
        self.config = config or RecorderConfig()
        self.clock = clock or MonotonicClock()
        self.on_status = on_status
        self._stop = threading.Event()  # every device thread ends
        self._cam_stop = threading.Event()  # the camera ends; the IMU records a little longer
        self._q: queue.Queue[tuple[str, Any]] = queue.Queue()
        self._frame_slots = threading.Semaphore(self.config.frame_queue)
        self.status = RecorderStatus()
        self._imu_progress = ImuProgress()
        self._warnings: list[str] = []

    def stop(self) -> None:
        """Ask for a clean stop (thread- and signal-safe): the camera stops at once, the IMU
        ``after_camera_end_s`` later, so the last frame's exposure has gyro coverage."""
        self._cam_stop.set()

    # ----------------------------------------------------------------- device threads
    def _imu_loop(self) -> None:
        assert self.imu is not None
        try:
            while not self._stop.is_set():
                batch = self.imu.read()
                if len(batch):
                    self._q.put(("imu", batch))
        except DeviceDisconnectedError as exc:
            self._q.put(("error", str(exc)))
        except RigError as exc:
            self._q.put(("error", f"IMU failed: {exc}"))

    def _camera_loop(self) -> None:
        import cv2

        assert self.camera is not None
        params = [cv2.IMWRITE_PNG_COMPRESSION, self.config.png_compression]
        try:
            while not (self._stop.is_set() or self._cam_stop.is_set()):
                frame = self.camera.read()
                if frame is None:
                    self._q.put(("camera-ended", None))
                    return
                image_info(frame.image)
                if self.config.frame_encoding == "png":
                    ok, buf = cv2.imencode(".png", frame.image, params)
                    if not ok:
                        self._q.put(("error", f"cannot PNG-encode frame {frame.index}"))
                        return
                    data = buf.tobytes()
                else:
                    data = np.ascontiguousarray(frame.image).tobytes()
                while not self._frame_slots.acquire(timeout=0.1):  # writer is behind
                    if self._stop.is_set() or self._cam_stop.is_set():
                        return
                self._q.put(("frame", (frame, data)))
        except DeviceDisconnectedError as exc:
            self._q.put(("error", str(exc)))
        except RigError as exc:
            self._q.put(("error", f"camera failed: {exc}"))

    # ----------------------------------------------------------------- writer
    def _write(self, log: RecLogWriter, kind: str, payload: Any, counts: dict[str, int]) -> None:
        if kind == "imu":
            b: ImuBatch = payload
            log.write_imu(
                int(b.host_ns[-1]), b.index, b.t_dev_us, b.host_ns, b.gyro_radps, b.accel_mps2
            )
            counts["imu"] += len(b)
            self._imu_progress.add(b)
        elif kind == "frame":
            frame, data = payload
            f: CameraFrame = frame
            log.write_frame(f, data, self.config.frame_encoding)
            self._frame_slots.release()
            counts["frames"] += 1

    def _snapshot(
        self,
        t_ns: int,
        start_ns: int,
        counts: dict[str, int],
        flushed: dict[str, int],
        log: RecLogWriter,
    ) -> RecorderStatus:
        s = self.status
        elapsed = (t_ns - start_ns) * 1e-9
        s.elapsed_s = elapsed
        s.imu_samples, s.frames = counts["imu"], counts["frames"]
        s.imu_rate_hz = counts["imu"] / elapsed if elapsed > 0 else 0.0
        s.fps = counts["frames"] / elapsed if elapsed > 0 else 0.0
        if self.imu is not None:
            st = self.imu.stats
            s.imu_crc_errors, s.imu_dropped, s.imu_resyncs = (
                st["crc_errors"],
                st["dropped"],
                st["resyncs"],
            )
            s.imu_discarded = st["received"] - st["kept"]
        if self.camera is not None:
            s.camera_dropped = int(self.camera.frames_dropped)
        s.flushed_imu_samples, s.flushed_frames = flushed["imu"], flushed["frames"]
        s.log_bytes = log.bytes_written
        return s

    def run(self) -> RecordResult:
        """Record until stopped; always leaves a finished log. Ctrl-C stops cleanly."""
        cfg = self.config
        log = RecLogWriter(self.log_path, self.metadata)
        threads = []
        if self.imu is not None:
            threads.append(threading.Thread(target=self._imu_loop, name="rec-imu", daemon=True))
        if self.camera is not None:
            threads.append(threading.Thread(target=self._camera_loop, name="rec-cam", daemon=True))
        start_ns = self.clock.now_ns()
        log.write_event(start_ns, "info", "recording started")
        for t in threads:
            t.start()
        counts = {"imu": 0, "frames": 0}
        flushed = dict(counts)
        next_flush = start_ns + round(cfg.flush_interval_s * 1e9)
        next_status = start_ns + round(cfg.status_interval_s * 1e9)
        stopped_by, error = "stop", None
        camera_end_ns: int | None = None
        timed_tail = False  # stopped by the user or the duration: the IMU's tail is timed
        try:
            while True:
                try:
                    kind, payload = self._q.get(timeout=0.02)
                except queue.Empty:
                    kind, payload = "", None
                if kind == "error":
                    error, stopped_by = payload, "error"
                    log.write_event(self.clock.now_ns(), "error", payload)
                    break
                if kind == "camera-ended" and cfg.stop_when_camera_ends and camera_end_ns is None:
                    stopped_by = "camera-ended"
                    camera_end_ns = self.clock.now_ns()
                self._write(log, kind, payload, counts)
                if camera_end_ns is not None and self._imu_done(camera_end_ns, timed_tail, log):
                    break
                now = self.clock.now_ns()
                if now >= next_flush:
                    self._flush(log, now, start_ns, counts, flushed)
                    next_flush = now + round(cfg.flush_interval_s * 1e9)
                if now >= next_status:
                    next_status = now + round(cfg.status_interval_s * 1e9)
                    if self.on_status is not None:
                        self.on_status(self._snapshot(now, start_ns, counts, flushed, log))
                if camera_end_ns is None and (
                    self._cam_stop.is_set()
                    or (cfg.duration_s is not None and now - start_ns >= cfg.duration_s * 1e9)
                ):
                    stopped_by = "stop" if self._cam_stop.is_set() else "duration"
                    self._cam_stop.set()
                    camera_end_ns, timed_tail = now, True
        except KeyboardInterrupt:
            stopped_by = "stop"
        except OSError as exc:  # the log's disk is full or gone: stop, keep what is flushed
            error, stopped_by = self._log_failed(exc), "error"
        finally:
            self._stop.set()
            for t in threads:
                t.join(timeout=5.0)
            try:
                while True:  # what the devices delivered before they stopped is kept
                    try:
                        kind, payload = self._q.get_nowait()
                    except queue.Empty:
                        break
                    if kind == "error" and error is None:
                        error, stopped_by = payload, "error"
                        log.write_event(self.clock.now_ns(), "error", payload)
                    self._write(log, kind, payload, counts)
                end_ns = self.clock.now_ns()
                self._flush(log, end_ns, start_ns, counts, flushed)
                log.write_event(end_ns, "info", f"recording stopped ({stopped_by})")
                log.finish()
            except OSError as exc:  # the log stays as far as it was flushed: recover reads it
                end_ns = self.clock.now_ns()
                if error is None:
                    error, stopped_by = self._log_failed(exc), "error"
                with suppress(OSError):
                    log._file.close()
        status = self._snapshot(end_ns, start_ns, counts, flushed, log)
        if self.on_status is not None:
            self.on_status(status)
        imu_stats = self.imu.stats if self.imu is not None else {}
        return RecordResult(self.log_path, status, imu_stats, stopped_by, error, self._warnings)

    def _log_failed(self, exc: OSError) -> str:
        reason = "no space left on the device" if exc.errno == errno.ENOSPC else exc.strerror
        return f"cannot write the log {self.log_path}: {reason or exc}"

    def _imu_done(
        self, camera_end_ns: int, timed: bool = False, log: RecLogWriter | None = None
    ) -> bool:
        """After the camera ended: has the IMU delivered what belongs to the recording?

        A timed tail ends once a sample taken ``after_camera_end_s`` after the camera's end has
        arrived (``ImuProgress``), or, for an IMU that lags or stalls, ``imu_tail_timeout_s`` of
        wall clock later than that, with a warning in the log and the result.
        """
        imu, cfg = self.imu, self.config
        if imu is None or imu.exhausted:
            return True
        if not timed and imu.finite:
            return False  # a source that ends by itself: wait for its last sample
        tail_ns = round(cfg.after_camera_end_s * 1e9)
        if self._imu_progress.reaches(camera_end_ns + tail_ns):
            return True
        now = self.clock.now_ns()
        if now - camera_end_ns < tail_ns + cfg.imu_tail_timeout_s * 1e9:
            return False
        last = self._imu_progress.last_dev_ns
        end_dev = self._imu_progress.device_ns_of(camera_end_ns)
        reached = (
            "no IMU sample"
            if last is None or end_dev is None
            else f"IMU samples to {(last - end_dev) * 1e-9:+.3f} s"
        )
        msg = (
            f"the IMU lagged: {reached} past the camera's end after waiting "
            f"{(now - camera_end_ns) * 1e-9:.1f} s, short of the {cfg.after_camera_end_s:g} s "
            "that cover the last exposure"
        )
        self._warnings.append(msg)
        if log is not None:
            log.write_event(now, "warning", msg)
        return True

    def _flush(
        self,
        log: RecLogWriter,
        now: int,
        start_ns: int,
        counts: dict[str, int],
        flushed: dict[str, int],
    ) -> None:
        stats: dict[str, Any] = {"imu_samples": counts["imu"], "frames": counts["frames"]}
        if self.imu is not None:
            stats["imu"] = self.imu.stats
        if self.camera is not None:
            stats["camera_dropped"] = int(self.camera.frames_dropped)
        log.write_stats(now, stats)
        log.flush()
        flushed.update(counts)


def rate_of(t_ns: np.ndarray) -> float:
    """Median rate (Hz) of increasing timestamps (ns); 0 for fewer than two."""
    if t_ns.size < 2:
        return 0.0
    dt = np.median(np.diff(t_ns))
    return float(1e9 / dt) if dt > 0 else 0.0
