"""Cameras selected by URL: V4L2/UVC and other OpenCV backends, video-file replays, simulation.

``v4l2://0`` and ``opencv://0`` open a device through OpenCV (``cv2.VideoCapture``);
``file:///path/video.mp4`` replays a file; ``sim://camera`` is :class:`VirtualCamera`. Openers
are registered by scheme in :data:`CAMERA_SCHEMES`; callers get a :class:`CameraSource`.

Timestamps: OpenCV's V4L2 backend reports the kernel buffer timestamp (CLOCK_MONOTONIC, ms) as
``CAP_PROP_POS_MSEC``; it is used when it lies within a second of the host clock, otherwise the
host time at grab is used and the frame says so (``stamp_source``). A file replay stamps each
frame with the replay start plus the frame's position in the file. Exposure: V4L2 reports
``exposure_time_absolute`` in 100 us units; other backends use unknown units, so the exposure is
then -1 unless the URL gives ``exposure_ms``.
"""

from __future__ import annotations

import threading
from typing import Any

from rigs.camera_types import CameraFrame, CameraSource
from rigs.clock import Clock, MonotonicClock
from rigs.errors import DeviceDisconnectedError, DeviceError, DeviceUrlError
from rigs.fake_camera import RenderFn, VirtualCamera, VirtualCameraConfig, dot_grid_renderer
from rigs.urls import DeviceUrl, SchemeRegistry

_DRIVER_STAMP_TOLERANCE_NS = 1_000_000_000


class OpenCvCamera:
    """A ``cv2.VideoCapture`` with timestamps, exposure and gap-based drop counting."""

    def __init__(
        self,
        capture: Any,
        url: str,
        kind: str,
        clock: Clock | None = None,
        exposure_ns: int | None = None,
        realtime: bool = False,
    ) -> None:
        import cv2

        self._cv2 = cv2
        self.capture = capture
        self.url = url
        self.kind = kind  # "v4l2", "opencv" or "file"
        self.clock = clock or MonotonicClock()
        self.exposure_override_ns = exposure_ns
        self.realtime = realtime
        self.fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self.frames_dropped = 0
        self._index = 0
        self._last_ns: int | None = None
        self._t_open_ns = self.clock.now_ns()
        self._stop = threading.Event()

    def _exposure_ns(self) -> int:
        if self.exposure_override_ns is not None:
            return self.exposure_override_ns
        if self.kind == "v4l2":
            value = float(self.capture.get(self._cv2.CAP_PROP_EXPOSURE))
            if value > 0:
                return round(value * 100_000)
        return -1

    def read(self) -> CameraFrame | None:
        cv2 = self._cv2
        ok, image = self.capture.read()
        host_ns = self.clock.now_ns()
        if not ok or image is None:
            if self.kind == "file":
                return None
            raise DeviceDisconnectedError(f"camera {self.url} stopped delivering frames")
        pos_ms = float(self.capture.get(cv2.CAP_PROP_POS_MSEC))
        if self.kind == "file":
            t_ns, source = self._t_open_ns + round(pos_ms * 1e6), "driver"
            if self.realtime:
                while (wait := t_ns - self.clock.now_ns()) > 0 and not self._stop.is_set():
                    self._stop.wait(min(wait * 1e-9, 0.05))
        elif pos_ms > 0 and abs(round(pos_ms * 1e6) - host_ns) < _DRIVER_STAMP_TOLERANCE_NS:
            t_ns, source = round(pos_ms * 1e6), "driver"
        else:
            t_ns, source = host_ns, "host"
        if self._last_ns is not None and self.fps > 0:
            missed = round((t_ns - self._last_ns) * self.fps / 1e9) - 1
            self.frames_dropped += max(0, missed)
        self._last_ns = t_ns
        frame = CameraFrame(self._index, image, t_ns, self._exposure_ns(), host_ns, source)
        self._index += 1
        return frame

    def close(self) -> None:
        self._stop.set()
        self.capture.release()


def _open_cv(u: DeviceUrl, clock: Clock | None) -> OpenCvCamera:
    import cv2

    u.check_keys({"width", "height", "fps", "exposure_ms", "realtime"})
    exposure_ms = u.get_opt_float("exposure_ms", 1e-3, 10_000.0)
    exposure_ns = None if exposure_ms is None else round(exposure_ms * 1e6)
    if u.scheme == "file":
        if not u.target:
            raise DeviceUrlError(f"{u.url}: no file path")
        cap = cv2.VideoCapture(u.target)
        if not cap.isOpened():
            raise DeviceError(f"cannot open video file {u.target}")
        return OpenCvCamera(
            cap, u.url, "file", clock, exposure_ns, realtime=u.get_int("realtime", 0, 0, 1) == 1
        )
    try:
        index = int(u.target)
    except ValueError:
        raise DeviceUrlError(f"{u.url}: camera index must be an integer") from None
    api = cv2.CAP_V4L2 if u.scheme == "v4l2" else cv2.CAP_ANY
    cap = cv2.VideoCapture(index, api)
    if not cap.isOpened():
        raise DeviceError(f"cannot open camera {u.url}")
    for key, prop in (
        ("width", cv2.CAP_PROP_FRAME_WIDTH),
        ("height", cv2.CAP_PROP_FRAME_HEIGHT),
        ("fps", cv2.CAP_PROP_FPS),
    ):
        if key in u.params:
            cap.set(prop, u.get_float(key, 0.0, 1.0, 100_000.0))
    return OpenCvCamera(cap, u.url, u.scheme, clock, exposure_ns)


def _open_rig_camera(u: DeviceUrl, clock: Clock | None) -> VirtualCamera:
    """A camera rendering a rigs.sim rig (frame rate and exposure from its preset).

    Not paced by default (``realtime=0``): the renderer is slower than real time at full
    resolution, and the frames' stamps follow the rig's schedule on the shared timeline
    whenever they are delivered, so nothing is dropped."""
    from rigs.sim.shared_rig import rig_from_params

    u.check_keys({"rig", "seed", "frames", "realtime"})
    shared = rig_from_params(u.url, u.params, clock)
    cfg = VirtualCameraConfig(
        fps=shared.fps,
        exposure_s=shared.exposure_s,
        n_frames=int(shared.rig.n_frames),
        realtime=u.get_int("realtime", 0, 0, 1) == 1,
        origin_ns=shared.origin_ns,
    )
    return VirtualCamera(shared.render, cfg, clock, u.url)


#: Camera openers by URL scheme: ``opener(url, clock, render) -> CameraSource``.
CAMERA_SCHEMES: SchemeRegistry[CameraSource] = SchemeRegistry("camera")


def open_camera(
    url: str, clock: Clock | None = None, render: RenderFn | None = None
) -> CameraSource:
    """Open the camera named by ``url``; ``render`` drives ``sim://camera`` (default: dots)."""
    return CAMERA_SCHEMES.open(url, clock, render)


@CAMERA_SCHEMES.register("v4l2", "opencv", "file")
def _open_opencv_url(u: DeviceUrl, clock: Clock | None, render: RenderFn | None) -> CameraSource:
    return _open_cv(u, clock)


@CAMERA_SCHEMES.register("sim")
def _open_sim(u: DeviceUrl, clock: Clock | None, render: RenderFn | None) -> CameraSource:
    url = u.url
    if u.target != "camera":
        raise DeviceUrlError(f"{url}: the simulated camera is sim://camera")
    if "rig" in u.params:
        return _open_rig_camera(u, clock)
    u.check_keys({"fps", "width", "height", "exposure_ms", "frames", "realtime", "noise", "seed"})
    frames = u.get_int("frames", -1, -1, 10**9)
    try:
        cfg = VirtualCameraConfig(
            fps=u.get_float("fps", 30.0, 0.1, 1000.0),
            exposure_s=u.get_float("exposure_ms", 10.0, 0.001, 10_000.0) * 1e-3,
            n_frames=None if frames < 0 else frames,
            realtime=u.get_int("realtime", 1, 0, 1) == 1,
        )
    except ValueError as exc:
        raise DeviceUrlError(f"{url}: {exc}") from None
    if render is None:
        render = dot_grid_renderer(
            u.get_int("width", 640, 16, 8192),
            u.get_int("height", 480, 16, 8192),
            noise=u.get_float("noise", 0.0, 0.0, 100.0),
            seed=u.get_int("seed", 0, 0, 2**31),
        )
    return VirtualCamera(render, cfg, clock, url)
