"""A video file (decoded with OpenCV) plus a gyro log in Gyroflow's ``.gcsv`` format.

``.gcsv`` (Gyroflow's documented IMU log): a ``GYROFLOW IMU LOG`` first line, ``key,value``
header lines (``tscale`` s per time unit, ``gscale`` rad/s per gyro unit, ``ascale`` g per
accelerometer unit, optionally ``frame_readout_time`` ms and ``orientation``), then a
``t,gx,gy,gz[,ax,ay,az]`` header and integer or decimal rows. Frame times are the container's
presentation times (``CAP_PROP_POS_MSEC``); the log's ``t`` and the video's are both taken to
start at 0 (the offset is the calibration's job). Gyroflow's ``orientation`` letters are not
taken as a known camera–IMU mapping: the session says ``axes_known: false``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.geometry.camera import Camera
from blurtrack.io.importers.common import (
    MAX_FRAMES,
    check_readout,
    exposure_ns,
    frame_start_ns,
    guessed_intrinsics,
    rate_hz,
    sorted_unique,
    text_lines,
)
from blurtrack.io.rosimage import check_size
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter

G_MPS2 = 9.80665
_SCALES = {"tscale": (1e-9, 10.0), "gscale": (1e-12, 1e3), "ascale": (1e-12, 1e3)}


def read_gcsv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict[str, str]]:
    """``(t_ns, omega_radps, accel_mps2 or None, header)`` of a Gyroflow ``.gcsv`` log."""
    lines = text_lines(path)
    if not lines or not lines[0].strip().upper().startswith("GYROFLOW IMU LOG"):
        raise ImportFormatError(f"{path}: not a Gyroflow log (first line 'GYROFLOW IMU LOG')")
    header: dict[str, str] = {}
    k = 1
    while k < len(lines) and not lines[k].strip().lower().startswith("t,"):
        key, _, value = lines[k].partition(",")
        header[key.strip().lower()] = value.strip()
        k += 1
    if k == len(lines):
        raise ImportFormatError(f"{path}: no 't,gx,gy,gz' column header")
    cols = [c.strip().lower() for c in lines[k].split(",")]
    if cols[:4] != ["t", "gx", "gy", "gz"]:
        raise ImportFormatError(f"{path}: columns must start t,gx,gy,gz, got {cols[:4]}")
    scales = {}
    for key, (lo, hi) in _SCALES.items():
        try:
            scales[key] = float(header.get(key, "1"))
        except ValueError:
            raise ImportFormatError(f"{path}: {key} {header[key]!r} is not a number") from None
        if not lo <= scales[key] <= hi:
            raise ImportFormatError(f"{path}: {key} {scales[key]} is outside [{lo}, {hi}]")
    has_acc = cols[4:7] == ["ax", "ay", "az"]
    n_use = 7 if has_acc else 4
    rows = []
    for n, line in enumerate(lines[k + 1 :], start=k + 2):
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) < n_use:
            raise ImportFormatError(f"{path} line {n}: expected {n_use} fields")
        try:
            rows.append([float(v) for v in parts[:n_use]])
        except ValueError:
            raise ImportFormatError(f"{path} line {n} is not numeric") from None
    data = np.asarray(rows, float).reshape(-1, n_use)
    if len(data) < 2 or not np.all(np.isfinite(data)):
        raise ImportFormatError(f"{path}: fewer than 2 samples or non-finite values")
    t_ns = np.round(data[:, 0] * scales["tscale"] * 1e9).astype(np.int64)
    omega = data[:, 1:4] * scales["gscale"]
    acc = data[:, 4:7] * scales["ascale"] * G_MPS2 if has_acc else None
    return t_ns, omega, acc, header


def import_video(
    src: str | Path,
    out: str | Path,
    *,
    gcsv: str | Path | None = None,
    exposure_s: float | None = None,
    readout_s: float | None = None,
    stamp: str = "start",
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Import ``src`` (a video file) with its gyro log ``gcsv`` (default: ``src`` with the
    suffix ``.gcsv``)."""
    src = Path(src)
    log = Path(gcsv) if gcsv is not None else src.with_suffix(".gcsv")
    if not src.is_file():
        raise ImportFormatError(f"video: {src} not found")
    exp = exposure_ns(exposure_s, "video")
    t_imu, omega, acc, header = read_gcsv(log)
    if readout_s is None:
        try:
            readout_s = float(header.get("frame_readout_time", "0")) * 1e-3
        except ValueError:
            raise ImportFormatError(f"{log}: frame_readout_time is not a number") from None
        readout_src = "the log's frame_readout_time" if "frame_readout_time" in header else "0"
    else:
        readout_src = "--readout-ms"
    readout = check_readout(readout_s, "video")
    if header.get("frame_readout_direction", "0") not in ("0", ""):
        raise ImportFormatError(f"{log}: only top-to-bottom readout (direction 0) is supported")
    cap = cv2.VideoCapture(str(src))
    if not cap.isOpened():
        raise ImportFormatError(f"video: {src} does not open as a video")
    limit = MAX_FRAMES if max_frames is None else min(int(max_frames), MAX_FRAMES)
    ok, frame = cap.read()
    if not ok:
        cap.release()
        raise ImportFormatError(f"video: {src} holds no decodable frame")
    h, w = frame.shape[:2]
    check_size(w, h, str(src))
    sel = sorted_unique(t_imu)
    assumptions = {
        "exposure_s": f"{exp * 1e-9} (from --exposure-ms; not in the container)",
        "readout_s": f"{readout} (from {readout_src})",
        "timestamps": f"container presentation times taken as the {stamp} of exposure",
        "timeshift_cam_imu_s": "0.0 (video and log both taken to start at t = 0; calibrate)",
        "camera": "GUESS: fx = fy = width, centred principal point",
        "R_cam_imu": (
            "UNKNOWN (axes_known: false): identity as a placeholder (gcsv orientation "
            f"{header.get('orientation', 'not given')!r} not trusted); calibrate decides"
        ),
    }
    meta = SessionMeta(
        camera=Camera((w, h), guessed_intrinsics(w, h), readout_s=readout),
        imu=ImuConfig(rate_hz=rate_hz(t_imu[sel], str(log)), axes_known=False),
        target_kind="natural",
        extra={"import": {"source": "video", "path": str(src), "assumptions": assumptions}},
    )
    n, prev = 0, None
    try:
        with SessionWriter(out, meta) as wr:
            while ok and n < limit:
                t_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
                if not np.isfinite(t_ms) or t_ms < 0:
                    raise ImportFormatError(f"video: frame {n} has no usable presentation time")
                t0 = frame_start_ns(round(t_ms * 1e6), stamp, exp, readout)
                if prev is not None and t0 <= prev:
                    raise ImportFormatError(f"video: frame {n} time {t_ms} ms is not increasing")
                if frame.shape[:2] != (h, w):
                    raise ImportFormatError(f"video: frame {n} changes size")
                wr.add_frame(t0, frame, exp)
                prev, n = t0, n + 1
                ok, frame = cap.read()
            wr.add_imu(t_imu[sel], omega[sel], None if acc is None else acc[sel])
    finally:
        cap.release()
    return {
        "frames": n,
        "gyro_samples": int(sel.size),
        "resolution": [w, h],
        "assumptions": assumptions,
    }
