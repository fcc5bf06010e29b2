"""The MARS logger app: ``movie_metadata.csv``, ``video_frames/frame<i>.jpg``,
``gyro_accel.csv``, optionally ``calib.npz``."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.geometry.camera import Camera
from blurtrack.io.importers.common import T_from_R, read_image, text_lines
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter

#: Assumed still-photo resolution (long, short side) of the MARS chessboard calibration.
MARS_STILL_SIZE = (4032.0, 3024.0)

#: Android device axes (x right, y up, z out of the screen, portrait) to the back camera's
#: (x right, y down, z forward) for frames stored upright in portrait. Only a best guess (the
#: app does not say how frames are rotated on disk): written with ``axes_known: false``.
ANDROID_PORTRAIT_R_CAM_IMU = np.diag([1.0, -1.0, -1.0])


def fit_radtan4(k: np.ndarray, r_max: float) -> tuple[tuple[float, float, float, float], float]:
    """Best ``k1, k2`` (OpenCV radtan) for a 5-coefficient ``k1 k2 p1 p2 k3`` model over
    normalised radii ``[0, r_max]``; returns the coefficients and the largest radial error."""
    k1, k2, p1, p2, k3 = (float(v) for v in k)
    r = np.linspace(0.0, r_max, 400)
    A = np.stack([r**3, r**5], axis=1)
    target = k1 * r**3 + k2 * r**5 + k3 * r**7
    sol, *_ = np.linalg.lstsq(A, target, rcond=None)
    err = float(np.max(np.abs(A @ sol - target)))
    return (float(sol[0]), float(sol[1]), p1, p2), err


def import_marslogger(src: str | Path, out: str | Path) -> dict[str, Any]:
    """Import a MARS logger recording into a session; returns a summary dict."""
    src = Path(src)
    rows = list(csv.reader(text_lines(src / "movie_metadata.csv")))
    if len(rows) < 2:
        raise ImportFormatError(f"{src}/movie_metadata.csv has no frames")
    head = [h.strip() for h in rows[0]]
    try:
        i_ts = head.index("Timestamp[nanosec]")
        i_exp = head.index("Exposure time[nanosec]")
        i_ro = head.index("Frame readout time[nanosec]")
        i_fx = head.index("fx[px]")
    except ValueError as exc:
        raise ImportFormatError(f"{src}/movie_metadata.csv: missing column ({exc})") from None
    try:
        meta_rows = [
            (int(r[i_ts]), int(r[i_exp]), int(r[i_ro]), float(r[i_fx])) for r in rows[1:] if r
        ]
    except (ValueError, IndexError):
        raise ImportFormatError(f"{src}/movie_metadata.csv: malformed row") from None
    gyro = list(csv.reader(text_lines(src / "gyro_accel.csv")))
    try:
        g = np.array([[float(v) for v in r[:7]] for r in gyro[1:] if r], dtype=float)
    except ValueError:
        raise ImportFormatError(f"{src}/gyro_accel.csv: non-numeric value") from None
    if g.ndim != 2 or g.shape[1] != 7 or len(g) < 2 or not np.all(np.isfinite(g)):
        raise ImportFormatError(f"{src}/gyro_accel.csv: expected rows 't_ns,gx,gy,gz,ax,ay,az'")
    t_ns = np.array([int(r[0]) for r in gyro[1:] if r], dtype=np.int64)
    first = read_image(src / "video_frames" / "frame0.jpg")
    h, w = first.shape[:2]
    long_side, short_side = max(w, h), min(w, h)
    assumptions: dict[str, Any] = {
        "timeshift_cam_imu_s": "0.0 (app note: camera and IMU share CLOCK_BOOTTIME)",
        "R_cam_imu": (
            "UNKNOWN (axes_known: false): best guess is Android portrait device axes to the "
            "back camera, diag(1, -1, -1); calibrate's axis search decides from the images"
        ),
    }
    calib_path = src / "calib.npz"
    dist: tuple[float, ...] = ()
    if calib_path.is_file():
        try:
            with np.load(calib_path, allow_pickle=False) as z:
                mtx, k = np.asarray(z["mtx"], float), np.asarray(z["dist"], float).ravel()
        except (OSError, ValueError, KeyError, TypeError, EOFError) as exc:
            raise ImportFormatError(
                f"{calib_path} is not a calib.npz with 'mtx' and 'dist' arrays ({exc})"
            ) from None
        if mtx.shape != (3, 3) or not (np.all(np.isfinite(mtx)) and np.all(np.isfinite(k))):
            raise ImportFormatError(
                f"{calib_path}: 'mtx' must be a finite 3x3 matrix and 'dist' finite, "
                f"got shapes {mtx.shape}, {k.shape}"
            )
        # The chessboard calibration is of full-sensor 4032x3024 stills (data README); the
        # video is the centred 16:9 crop of the sensor scaled to long_side.
        still_long, still_short = MARS_STILL_SIZE
        s = long_side / still_long
        crop = (still_short - short_side / s) / 2.0
        portrait = h > w
        fx, fy = mtx[0, 0] * s, mtx[1, 1] * s
        cx_still, cy_still = mtx[0, 2], mtx[1, 2]
        if portrait:
            cx, cy = (cx_still - crop + 0.5) * s - 0.5, (cy_still + 0.5) * s - 0.5
        else:
            cx, cy = (cx_still + 0.5) * s - 0.5, (cy_still - crop + 0.5) * s - 0.5
        r_max = float(np.hypot(w / 2 / fx, h / 2 / fy))
        if k.size >= 5:
            dist, err = fit_radtan4(k[:5], r_max)
            assumptions["distortion"] = (
                f"k1 k2 refitted to the 5-coefficient chessboard model "
                f"over the video's field of view (max radial error "
                f"{err:.2e} normalised)"
            )
        else:
            dist = tuple(float(v) for v in k[:4])
        intr = (fx, fy, cx, cy)
        assumptions["intrinsics"] = (
            f"calib.npz scaled by {s:.5f} with a {crop:.1f}-px crop of the still's short side"
        )
    else:
        fx = meta_rows[0][3] * long_side / 4032.0
        intr = (fx, fx, (w - 1) / 2.0, (h - 1) / 2.0)
        assumptions["intrinsics"] = "app-reported fx scaled from a 4032-px sensor; centred"
    readout = meta_rows[0][2] * 1e-9
    meta = SessionMeta(
        camera=Camera((w, h), intr, "radtan" if dist else "none", dist, readout_s=readout),
        imu=ImuConfig(
            rate_hz=float(1e9 / np.median(np.diff(t_ns))),
            T_cam_imu=np.asarray(T_from_R(ANDROID_PORTRAIT_R_CAM_IMU)),
            axes_known=False,
        ),
        target_kind="natural",
        extra={"import": {"source": "marslogger", "path": str(src), "assumptions": assumptions}},
    )
    order = np.argsort(t_ns, kind="stable")
    keep = np.r_[True, np.diff(t_ns[order]) > 0]  # the app repeats stamps rarely; drop repeats
    with SessionWriter(out, meta) as wr:
        for i, (ts, exp, _, _) in enumerate(meta_rows):
            img = first if i == 0 else read_image(src / "video_frames" / f"frame{i}.jpg")
            if img.shape[:2] != (h, w):
                raise ImportFormatError(f"{src}/video_frames/frame{i}.jpg has a different size")
            wr.add_frame(ts, img, exp)
        sel = order[keep]
        wr.add_imu(t_ns[sel], g[sel, 1:4], g[sel, 4:7])
    covered = [
        bool(ts >= t_ns.min() and ts + exp + readout * 1e9 <= t_ns.max())
        for ts, exp, _, _ in meta_rows
    ]
    return {
        "frames": len(meta_rows),
        "gyro_samples": int(sel.size),
        "resolution": [w, h],
        "frames_covered_by_gyro": int(sum(covered)),
        "assumptions": assumptions,
    }
