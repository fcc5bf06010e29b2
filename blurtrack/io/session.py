"""Session folders (docs/conventions.md): read, write incrementally, and validate.

Layout (EuRoC/ASL style)::

    session/session.yaml                 format: blurtrack-session/1, camera, imu, target
    session/cam0/data.csv                #timestamp [ns],filename,exposure [ns]
    session/cam0/data/<timestamp>.png
    session/imu0/data.csv                #timestamp [ns],w_x,w_y,w_z [rad s^-1][,a_x,a_y,a_z]
    session/truth.yaml                   simulated sessions only

The writer appends and flushes as it goes, so whatever it wrote before a crash stays readable.
The reader refuses malformed input with one-line :class:`~blurtrack.errors.SessionError` messages;
writer and reader both refuse values outside the physical bounds of :mod:`blurtrack.io.bounds`.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from blurtrack.errors import BlurTrackError, ConfigError, SessionError
from blurtrack.geometry.camera import Camera
from blurtrack.io import atomic, bounds, images
from blurtrack.io.csvtable import check_strictly_increasing, numeric_column, read_csv_table
from blurtrack.io.yamlio import read_yaml, write_yaml

FORMAT = "blurtrack-session/1"
CAM_HEADER = "#timestamp [ns],filename,exposure [ns]"
IMU_HEADER = "#timestamp [ns],w_x [rad s^-1],w_y [rad s^-1],w_z [rad s^-1]"
ACC_HEADER = ",a_x [m s^-2],a_y [m s^-2],a_z [m s^-2]"
TARGET_KINDS = ("laser-grid", "natural")


@dataclass(frozen=True)
class ImuConfig:
    """What the rig says about its IMU (guesses; ``axes_known: false``: axes to be searched)."""

    rate_hz: float = 200.0
    T_cam_imu: np.ndarray = field(default_factory=lambda: np.eye(4))
    timeshift_cam_imu: float = 0.0
    axes_known: bool = True

    def __post_init__(self) -> None:
        T = np.array(self.T_cam_imu, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise SessionError("imu.T_cam_imu must be a finite 4x4 matrix")
        rate = float(self.rate_hz)
        if not (math.isfinite(rate) and rate > 0):
            raise SessionError(f"imu.rate_hz must be positive, got {self.rate_hz}")
        if not isinstance(self.axes_known, bool):
            raise SessionError(f"imu.axes_known must be true or false, got {self.axes_known!r}")
        T.setflags(write=False)
        object.__setattr__(self, "T_cam_imu", T)
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "timeshift_cam_imu", float(self.timeshift_cam_imu))


@dataclass(frozen=True)
class SessionMeta:
    """The content of ``session.yaml``; unknown keys are kept in ``extra``."""

    camera: Camera
    imu: ImuConfig = field(default_factory=ImuConfig)
    target_kind: str = "laser-grid"
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.target_kind not in TARGET_KINDS:
            raise SessionError(
                f"target.kind must be one of {TARGET_KINDS}, got {self.target_kind!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        c = self.camera
        d: dict[str, Any] = {
            "format": FORMAT,
            "camera": {
                "resolution": list(c.resolution),
                "intrinsics": list(c.intrinsics),
                "distortion_model": c.distortion_model,
                "distortion_coeffs": list(c.distortion_coeffs),
                "readout_s": c.readout_s,
            },
            "imu": {
                "rate_hz": self.imu.rate_hz,
                "T_cam_imu": self.imu.T_cam_imu.tolist(),
                "timeshift_cam_imu": self.imu.timeshift_cam_imu,
                "axes_known": self.imu.axes_known,
            },
            "target": {"kind": self.target_kind},
        }
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> SessionMeta:
        if not isinstance(d, dict):
            raise SessionError("session.yaml must be a mapping")
        if d.get("format") != FORMAT:
            raise SessionError(f"session.yaml: format must be {FORMAT!r}, got {d.get('format')!r}")
        try:
            c, i = d["camera"], d.get("imu") or {}
            camera = Camera(
                resolution=tuple(c["resolution"]),
                intrinsics=tuple(c["intrinsics"]),
                distortion_model=c.get("distortion_model", "none"),
                distortion_coeffs=tuple(c.get("distortion_coeffs") or ()),
                readout_s=c.get("readout_s", 0.0),
            )
            imu = ImuConfig(
                rate_hz=i.get("rate_hz", 200.0),
                T_cam_imu=i.get("T_cam_imu", np.eye(4).tolist()),
                timeshift_cam_imu=i.get("timeshift_cam_imu", 0.0),
                axes_known=i.get("axes_known", True),
            )
            kind = (d.get("target") or {}).get("kind", "laser-grid")
        except KeyError as exc:
            raise SessionError(f"session.yaml lacks the key {exc.args[0]!r}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise SessionError(f"session.yaml: malformed value ({exc})") from None
        except BlurTrackError as exc:
            raise SessionError(f"session.yaml: {exc}") from None
        extra = {k: v for k, v in d.items() if k not in ("format", "camera", "imu", "target")}
        return cls(camera=camera, imu=imu, target_kind=kind, extra=extra)


def safe_member(folder: Path, name: str) -> Path:
    """``folder / name`` for a plain file name; refuses paths, ``..`` and absolute names."""
    if (
        not name
        or "/" in name
        or "\\" in name
        or name in (".", "..")
        or os.path.isabs(name)
        or "\x00" in name
    ):
        raise SessionError(f"file name {name!r} must be a plain name inside {folder}")
    return folder / name


def encode_frame(image: np.ndarray, what: str = "frame") -> bytes:
    """A frame (uint8/uint16 gray or BGR) as the PNG bytes a session stores."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16) or img.ndim not in (2, 3):
        raise SessionError(
            f"{what}: image must be uint8/uint16 gray or BGR, got {img.dtype} {img.shape}"
        )
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise SessionError(f"{what}: PNG encoding failed")
    return buf.tobytes()


class SessionWriter:
    """Write a session folder incrementally; every call leaves a readable folder behind.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp()) / "s"
    >>> meta = SessionMeta(Camera((4, 3), (2.0, 2.0, 1.5, 1.0)))
    >>> with SessionWriter(d, meta) as w:
    ...     w.add_frame(1000, np.zeros((3, 4), np.uint8), 500)
    ...     w.add_imu(np.array([0, 2000]), np.zeros((2, 3)))
    >>> load_session(d).frames.timestamp_ns.tolist()
    [1000]
    """

    def __init__(self, folder: str | Path, meta: SessionMeta) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and (not self.folder.is_dir() or any(self.folder.iterdir())):
            raise SessionError(f"refusing to write a session into non-empty {self.folder}")
        (self.folder / "cam0" / "data").mkdir(parents=True, exist_ok=True)
        (self.folder / "imu0").mkdir(parents=True, exist_ok=True)
        self.meta = meta
        write_yaml(self.folder / "session.yaml", meta.to_dict())
        self._cam = (self.folder / "cam0" / "data.csv").open("w", encoding="utf-8")
        self._cam.write(CAM_HEADER + "\n")
        self._cam.flush()
        self._imu: io.TextIOWrapper | None = None
        self._imu_accel: bool | None = None
        self._last_frame_ns: int | None = None
        self._last_exposure_ns = 0
        self._last_interval_ns: int | None = None
        self._last_imu_ns: int | None = None
        self.n_frames = 0
        self.n_imu = 0

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(check_last=exc_type is None)

    def add_frame(self, timestamp_ns: int, image: np.ndarray, exposure_ns: int) -> None:
        """Write ``cam0/data/<timestamp>.png`` (atomically) and its CSV row."""
        self.add_png(timestamp_ns, encode_frame(image, f"frame {int(timestamp_ns)}"), exposure_ns)

    def add_png(self, timestamp_ns: int, png: bytes, exposure_ns: int) -> None:
        """:meth:`add_frame` of a frame already encoded by :func:`encode_frame` (importers
        encode on several threads: PNG encoding is most of an import's time)."""
        ts = int(timestamp_ns)
        if self._last_frame_ns is not None and ts <= self._last_frame_ns:
            raise SessionError(
                f"frame timestamp {ts} is not after the previous {self._last_frame_ns}"
            )
        if int(exposure_ns) <= 0:
            raise SessionError(f"frame {ts}: exposure must be positive, got {exposure_ns} ns")
        if self._last_frame_ns is not None:  # the previous frame's exposure vs its interval
            bounds.check_exposures(
                np.array([self._last_frame_ns, ts]),
                np.array([self._last_exposure_ns, 0]),
                "session being written: cam0/data.csv",
                self.n_frames + 1,
            )
        name = f"{ts}.png"
        path = self.folder / "cam0" / "data" / name
        atomic.write_bytes_atomic(path, png)
        self._cam.write(f"{ts},{name},{int(exposure_ns)}\n")
        self._cam.flush()
        if self._last_frame_ns is not None:
            self._last_interval_ns = ts - self._last_frame_ns
        self._last_frame_ns = ts
        self._last_exposure_ns = int(exposure_ns)
        self.n_frames += 1

    def add_imu(
        self, t_ns: np.ndarray, omega_radps: np.ndarray, accel_mps2: np.ndarray | None = None
    ) -> None:
        """Append gyro (and optionally accelerometer) samples ``(N,)``, ``(N, 3)``."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        w = np.asarray(omega_radps, dtype=float).reshape(-1, 3)
        if w.shape[0] != t.size:
            raise SessionError(f"add_imu: {t.size} timestamps but {w.shape[0]} gyro rows")
        a = None if accel_mps2 is None else np.asarray(accel_mps2, float).reshape(-1, 3)
        if a is not None and a.shape[0] != t.size:
            raise SessionError(f"add_imu: {t.size} timestamps but {a.shape[0]} accel rows")
        if self._imu_accel is None:
            self._imu_accel = a is not None
            self._imu = (self.folder / "imu0" / "data.csv").open("w", encoding="utf-8")
            self._imu.write(IMU_HEADER + (ACC_HEADER if a is not None else "") + "\n")
        elif self._imu_accel != (a is not None):
            raise SessionError("add_imu: accelerometer columns must be given always or never")
        if t.size == 0:
            return
        where = "session being written: imu0/data.csv"
        bounds.check_gyro(w, where, self.n_imu + 2)
        if a is not None:
            bounds.check_accel(a, where, self.n_imu + 2)
        prev = self._last_imu_ns
        if np.any(np.diff(t) <= 0) or (prev is not None and t[0] <= prev):
            raise SessionError("add_imu: IMU timestamps must be strictly increasing")
        cols = [t[:, None].astype(object), w] + ([a] if a is not None else [])
        block = np.concatenate([np.asarray(c, dtype=object) for c in cols], axis=1)
        assert self._imu is not None
        self._imu.write(
            "".join(
                f"{row[0]}," + ",".join(repr(float(v)) for v in row[1:]) + "\n" for row in block
            )
        )
        self._imu.flush()
        self._last_imu_ns = int(t[-1])
        self.n_imu += t.size

    def write_truth(self, truth: dict[str, Any]) -> None:
        write_yaml(self.folder / "truth.yaml", truth)

    def close(self, check_last: bool = True) -> None:
        """Close the tables; ``check_last``: also check the last frame's exposure against the
        interval before it (:func:`blurtrack.io.bounds.check_exposures`)."""
        try:
            if self._imu is None:  # a session always has an imu0/data.csv, possibly empty
                self.add_imu(np.zeros(0, np.int64), np.zeros((0, 3)))
            if check_last and self._last_frame_ns is not None and self._last_interval_ns:
                last = self._last_frame_ns
                bounds.check_exposures(
                    np.array([last - self._last_interval_ns, last]),
                    np.array([0, self._last_exposure_ns]),
                    "session being written: cam0/data.csv",
                    self.n_frames,
                )
        finally:
            for f in (self._cam, self._imu):
                if f is not None and not f.closed:
                    f.close()


@dataclass(frozen=True)
class Session:
    """A loaded, validated session (images are read on demand)."""

    folder: Path
    meta: SessionMeta
    frames: pd.DataFrame
    imu_t_ns: np.ndarray
    omega_radps: np.ndarray
    accel_mps2: np.ndarray | None
    _truth_cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def truth(self) -> dict[str, Any] | None:
        """``truth.yaml`` (simulated sessions), parsed on first use: it can be megabytes."""
        if "truth" not in self._truth_cache:
            path = self.folder / "truth.yaml"
            if not path.exists():
                self._truth_cache["truth"] = None
            else:
                try:
                    self._truth_cache["truth"] = read_yaml(path, "truth.yaml")
                except ConfigError as exc:
                    raise SessionError(str(exc)) from None
        return self._truth_cache["truth"]

    @property
    def has_truth(self) -> bool:
        return (self.folder / "truth.yaml").exists()

    @property
    def frame_times_s(self) -> np.ndarray:
        return self.frames["timestamp_ns"].to_numpy(np.int64) * 1e-9

    @property
    def imu_times_s(self) -> np.ndarray:
        return self.imu_t_ns * 1e-9

    @property
    def exposures_s(self) -> np.ndarray:
        return self.frames["exposure_ns"].to_numpy(np.int64) * 1e-9

    def image_path(self, i: int) -> Path:
        return safe_member(self.folder / "cam0" / "data", str(self.frames["filename"].iloc[i]))

    def read_image(self, i: int) -> np.ndarray:
        """Frame ``i`` as stored (uint8/uint16, gray or BGR)."""
        path = self.image_path(i)
        try:
            img = images.read_image(path)
        except images.ImageError as exc:
            raise SessionError(str(exc)) from None
        w, h = self.meta.camera.resolution
        if img.shape[:2] != (h, w):
            raise SessionError(
                f"image {path} is {img.shape[1]}x{img.shape[0]}, session says {w}x{h}"
            )
        return img

    def gyro(self, max_gap_s: float | None = None):
        """The IMU samples as a :class:`~blurtrack.geometry.gyro.GyroTrace` (IMU clock, seconds)."""
        from blurtrack.geometry.gyro import GyroTrace

        return GyroTrace(self.imu_times_s, self.omega_radps, max_gap_s)

    def initial_calibration(self):
        """The rig's own guesses (session.yaml) as a calibration."""
        from blurtrack.geometry.calibration import Calibration

        T = self.meta.imu.T_cam_imu
        try:
            return Calibration(
                camera=self.meta.camera,
                R_cam_imu=T[:3, :3],
                t_cam_imu_m=T[:3, 3],
                timeshift_cam_imu_s=self.meta.imu.timeshift_cam_imu,
            )
        except ConfigError as exc:
            raise SessionError(f"session.yaml imu block: {exc}") from None


def load_session(folder: str | Path, max_gyro_gap_s: float | None = None) -> Session:
    """Load and validate a session folder.

    Args:
        max_gyro_gap_s: if given, refuse gyro gaps longer than this inside the span of the
            frames' exposures (otherwise gaps are left to the coverage checks at use time).
    """
    root = Path(folder)
    if not root.is_dir():
        raise SessionError(f"session folder not found: {root}")
    try:
        meta = SessionMeta.from_dict(read_yaml(root / "session.yaml", "session.yaml"))
    except ConfigError as exc:
        raise SessionError(str(exc)) from None
    cam_csv = root / "cam0" / "data.csv"
    cdf = read_csv_table(cam_csv, "camera table", (3,))
    ts = numeric_column(cdf, 0, cam_csv, True)
    exp = numeric_column(cdf, 2, cam_csv, True)
    check_strictly_increasing(ts, cam_csv)
    if np.any(exp <= 0):
        raise SessionError(
            f"{cam_csv}: exposure must be positive (line {int(np.flatnonzero(exp <= 0)[0]) + 2})"
        )
    names = [str(n) for n in cdf[1]]
    bounds.check_unique_names(names, str(cam_csv))
    bounds.check_exposures(ts, exp, str(cam_csv))
    data_dir = root / "cam0" / "data"
    for n in names:
        if not safe_member(data_dir, n).is_file():
            raise SessionError(f"{cam_csv}: image {n} is missing from {data_dir}")
    frames = pd.DataFrame({"timestamp_ns": ts, "filename": names, "exposure_ns": exp})
    imu_csv = root / "imu0" / "data.csv"
    idf = read_csv_table(imu_csv, "IMU table", (4, 7))
    t_imu = numeric_column(idf, 0, imu_csv, True)
    omega = (
        np.stack([numeric_column(idf, k, imu_csv, False) for k in (1, 2, 3)], axis=1)
        if len(idf)
        else np.zeros((0, 3))
    )
    accel = None
    if idf.shape[1] == 7:
        accel = (
            np.stack([numeric_column(idf, k, imu_csv, False) for k in (4, 5, 6)], axis=1)
            if len(idf)
            else np.zeros((0, 3))
        )
    check_strictly_increasing(t_imu, imu_csv)
    bounds.check_gyro(omega, str(imu_csv))
    if accel is not None:
        bounds.check_accel(accel, str(imu_csv))
    session = Session(root, meta, frames, t_imu, omega, accel)
    if max_gyro_gap_s is not None and len(frames) and t_imu.size:
        shift = meta.imu.timeshift_cam_imu
        lo = session.frame_times_s[0] + shift
        hi = session.frame_times_s[-1] + session.exposures_s[-1] + meta.camera.readout_s + shift
        tt = session.imu_times_s
        gaps = np.flatnonzero((np.diff(tt) > max_gyro_gap_s) & (tt[1:] > lo) & (tt[:-1] < hi))
        if gaps.size:
            k = int(gaps[0])
            raise SessionError(
                f"{imu_csv}: gyro gap of {1e3 * (tt[k + 1] - tt[k]):.1f} ms after "
                f"timestamp {t_imu[k]} (limit {1e3 * max_gyro_gap_s:.1f} ms)"
            )
    return session
