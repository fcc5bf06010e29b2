"""DeepGyro's SHIELD tablet burst: ``images/images.txt`` with ``timestamp_ns exposure_ns`` per
frame, ``imu/imu.txt`` Android sensor log ``type timestamp_ns x y z``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.geometry.camera import Camera
from blurtrack.io.importers.common import T_from_R, read_image, text_lines
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter

#: DeepGyro's published camera (data README): full-resolution intrinsics; the gyro's x and y
#: are swapped relative to the camera's. A pure swap is a reflection (det -1), so it is not a
#: rotation; the proper rotation below (z flipped as well) is only the importer's best guess and
#: is written with ``axes_known: false`` (docs/conventions.md, "Frames and units").
DEEPGYRO_INTRINSICS = (1558.6899, 1558.6899, 939.6533, 518.4131)
DEEPGYRO_R_CAM_IMU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Assumed rolling-shutter readout of the SHIELD sensor at 1080p30 (not published).
DEEPGYRO_READOUT_S = 0.020


def import_deepgyro(src: str | Path, out: str | Path) -> dict[str, Any]:
    """Import DeepGyro's ``myrawdata`` layout into a session; returns a summary dict."""
    src = Path(src)
    frames: list[tuple[int, int]] = []
    for n, line in enumerate(text_lines(src / "images" / "images.txt"), start=1):
        parts = line.split()
        if not parts:
            continue
        try:
            ts, exp = int(parts[0]), int(parts[1])
        except (ValueError, IndexError):
            raise ImportFormatError(
                f"{src}/images/images.txt line {n}: expected "
                f"'timestamp_ns exposure_ns', got {line!r}"
            ) from None
        frames.append((ts, exp))
    gyro_t, gyro_w = [], []
    for n, line in enumerate(text_lines(src / "imu" / "imu.txt"), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 5:
            raise ImportFormatError(
                f"{src}/imu/imu.txt line {n}: expected 5 fields 'type timestamp_ns x y z'"
            )
        try:
            kind, ts = int(parts[0]), int(parts[1])
            xyz = [float(v) for v in parts[2:]]
        except ValueError:
            raise ImportFormatError(f"{src}/imu/imu.txt line {n} is not numeric") from None
        if kind == 4:  # Android TYPE_GYROSCOPE
            if not np.all(np.isfinite(xyz)):
                raise ImportFormatError(f"{src}/imu/imu.txt line {n}: non-finite gyro value")
            gyro_t.append(ts)
            gyro_w.append(xyz)
    if not frames or len(gyro_t) < 2:
        raise ImportFormatError(f"{src}: no frames or fewer than 2 gyro samples")
    order = np.argsort(gyro_t, kind="stable")
    first = read_image(src / "images" / f"{1:04d}.jpg")
    h, w = first.shape[:2]
    assumptions = {
        "timeshift_cam_imu_s": "0.0 (not published; to be calibrated)",
        "readout_s": f"{DEEPGYRO_READOUT_S} (assumed for a 1080p30 phone-class sensor)",
        "R_cam_imu": (
            "UNKNOWN (axes_known: false): best guess is the data README's x/y swap completed to "
            "a rotation by z -> -z; the README's own note says this guess predicts the pan "
            "backwards, so calibrate's axis search decides from the images"
        ),
    }
    meta = SessionMeta(
        camera=Camera((w, h), DEEPGYRO_INTRINSICS, readout_s=DEEPGYRO_READOUT_S),
        imu=ImuConfig(
            rate_hz=float(1e9 / np.median(np.diff(np.sort(gyro_t)))),
            T_cam_imu=np.asarray(T_from_R(DEEPGYRO_R_CAM_IMU)),
            axes_known=False,
        ),
        target_kind="natural",
        extra={"import": {"source": "deepgyro", "path": str(src), "assumptions": assumptions}},
    )
    with SessionWriter(out, meta) as wr:
        for i, (ts, exp) in enumerate(frames, start=1):
            img = first if i == 1 else read_image(src / "images" / f"{i:04d}.jpg")
            if img.shape[:2] != (h, w):
                raise ImportFormatError(
                    f"{src}/images/{i:04d}.jpg is {img.shape[1]}x"
                    f"{img.shape[0]}, the first frame {w}x{h}"
                )
            wr.add_frame(ts, img, exp)
        wr.add_imu(np.asarray(gyro_t, np.int64)[order], np.asarray(gyro_w)[order])
    return {
        "frames": len(frames),
        "gyro_samples": len(gyro_t),
        "resolution": [w, h],
        "assumptions": assumptions,
    }
