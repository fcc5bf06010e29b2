"""Predicted blur trajectories drawn over recorded frames (PNG), for a quick visual check."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from blurtrack.errors import CoverageError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.io.images import write_image
from blurtrack.io.session import Session


def trajectory_grid(
    model: BlurModel, frame_t_s: float, exposure_s: float, nx: int = 9, ny: int = 6, n_t: int = 24
) -> np.ndarray:
    """Image paths ``(nx*ny, n_t, 2)`` of a grid of scene points over one exposure.

    Each point is placed on the grid at the frame's reference time (mid-exposure of the centre
    row); its path covers its own row's exposure window (rolling shutter).
    """
    cam = model.camera
    W, H = cam.resolution
    u, v = np.meshgrid(np.linspace(0.08, 0.92, nx) * (W - 1), np.linspace(0.1, 0.9, ny) * (H - 1))
    px = np.stack([u.ravel(), v.ravel()], axis=1)
    t_ref = model.default_reference_time(frame_t_s, exposure_s)
    _start, _, t0, t1 = model.streak_endpoints(px, t_ref, frame_t_s, exposure_s)
    times = t0[:, None] + (t1 - t0)[:, None] * np.linspace(0.0, 1.0, n_t)[None, :]
    return model.point_track(px, np.full(len(px), t_ref), times)


def draw_tracks(image: np.ndarray, tracks: np.ndarray, thickness: int = 2) -> np.ndarray:
    """Draw paths ``(N, T, 2)`` on a copy of ``image`` (green, red dot at the start)."""
    img = image
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    out = img.copy()
    scale = 16  # cv2 drawing with 4 fractional bits for sub-pixel positions
    for tr in tracks:
        pts = np.round(tr * scale).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(out, [pts], False, (0, 255, 0), thickness, cv2.LINE_AA, shift=4)
        cv2.circle(
            out, tuple(int(v) for v in pts[0, 0]), 3 * scale, (0, 0, 255), -1, cv2.LINE_AA, shift=4
        )
    return out


def draw_session_overlays(
    session: Session, calib: Calibration, out_dir: str | Path, frames: list[int] | None = None
) -> dict[str, object]:
    """Write ``overlay_<i>.png`` for the chosen frames; frames the gyro does not cover are
    listed under ``skipped`` with the reason, not drawn."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model = BlurModel(calib, session.gyro())
    idx = list(range(len(session.frames))) if frames is None else frames
    written, skipped = [], {}
    for i in idx:
        t, exp = float(session.frame_times_s[i]), float(session.exposures_s[i])
        try:
            tracks = trajectory_grid(model, t, exp)
        except CoverageError as exc:
            skipped[int(i)] = str(exc)
            continue
        path = out / f"overlay_{i:03d}.png"
        write_image(path, draw_tracks(session.read_image(i), tracks))
        written.append(str(path))
    return {"written": written, "skipped": skipped}
