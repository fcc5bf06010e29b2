"""The source paper's blur synthesis, kept for side-by-side comparison (``--mode paper``).

Luan et al. synthesise blur with three approximations that :mod:`blurtrack.synth.render`
avoids, reproduced here on purpose:

* **per-axis small-angle rotation**: angles summed per axis, then ``Rz Ry Rx``
  (``BlurModel(rotation_model="small_angle")``, the core's implementation);
* **four-corner homography**: each sub-step warps the whole image with the homography fitted to
  where the four image corners move (no rolling shutter, no lens distortion);
* **sRGB averaging**: the 8-bit values are averaged directly, without linearisation.

Sub-steps follow the paper: each gyro interval ``j`` inside the exposure is split into
``n_j = ceil(max corner displacement over the interval in px)`` sub-steps (at least 1), the
warps are averaged per interval, and intervals are weighted by their duration (so the result
is a time average, as a blur must be). The whole frame is exposed over the centre row's
window, so the paper's blur and the exact one share the reference time and can be compared
pixel for pixel.
"""

from __future__ import annotations

import cv2
import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.synth.render import (
    BORDERS,
    NodeGrid,
    RenderResult,
    RenderSettings,
    four_channels,
    source_positions,
)


def paper_model(calib: Calibration, trace: GyroTrace) -> BlurModel:
    """The paper's motion model: small-angle rotations, global shutter, same intrinsics."""
    return BlurModel(calib.with_(readout_s=0.0), trace, rotation_model="small_angle")


def paper_window(calib: Calibration, frame_t_s: float) -> float:
    """Start of the global exposure window the paper mode uses: the centre row's start."""
    cam = calib.camera
    return float(cam.row_start_s(frame_t_s, (cam.height - 1) / 2))


def render_paper(
    sharp_srgb: np.ndarray,
    calib: Calibration,
    trace: GyroTrace,
    frame_t_s: float,
    exposure_s: float,
    t_ref_s: float | None = None,
    settings: RenderSettings | None = None,
) -> RenderResult:
    """Paper-style blur of ``sharp_srgb`` (float32 sRGB values, ``(H, W[, C])``).

    ``t_ref`` defaults to the middle of the centre row's exposure (as the exact renderer).
    """
    st = settings or RenderSettings()
    cam = calib.camera
    W, H = cam.resolution
    img = np.asarray(sharp_srgb)
    if img.dtype != np.float32 or img.shape[:2] != (H, W):
        raise SynthesisError(
            f"sharp image must be float32 {H}x{W}[xC], got {img.dtype} {img.shape}"
        )
    model = paper_model(calib, trace)
    t0 = paper_window(calib, frame_t_s)
    t1 = t0 + exposure_s
    t_ref = t0 + exposure_s / 2 if t_ref_s is None else float(t_ref_s)
    t_gyro_cam = trace.t_s - calib.timeshift_cam_imu_s
    bounds = np.concatenate([[t0], t_gyro_cam[(t_gyro_cam > t0) & (t_gyro_cam < t1)], [t1]])
    corners = np.array([[0.0, 0.0], [W - 1.0, 0.0], [W - 1.0, H - 1.0], [0.0, H - 1.0]])
    pos = model.point_track(corners, np.full(4, t_ref), np.broadcast_to(bounds, (4, bounds.size)))
    # point_track gives where corners seen at t_ref are at time t; the paper's n_j counts that
    # motion, identical in size to the inverse map's at sub-pixel level.
    step = np.max(np.linalg.norm(np.diff(pos, axis=1), axis=-1), axis=0)
    n_j = np.maximum(1, np.ceil(step - 1e-9)).astype(int)
    if int(n_j.sum()) > st.max_samples:
        raise SynthesisError(
            f"paper mode would need {int(n_j.sum())} sub-steps (limit {st.max_samples})"
        )
    border = BORDERS[st.border]
    work = four_channels(img)
    acc: np.ndarray = np.zeros(work.shape, np.float32)
    part = np.empty_like(acc)
    warped = np.empty_like(acc)
    times, weights = [], []
    for j, n in enumerate(n_j):
        ta, tb = bounds[j], bounds[j + 1]
        ts = ta + (np.arange(n) + 0.5) / n * (tb - ta)
        times.append(ts)
        weights.append(np.full(n, (tb - ta) / (n * exposure_s)))
        src = model.warp(np.tile(corners, (n, 1)), np.repeat(ts, 4), np.full(4 * n, t_ref))
        part[...] = 0
        for k in range(n):
            Hk = cv2.getPerspectiveTransform(
                corners.astype(np.float32), src[4 * k : 4 * k + 4].astype(np.float32)
            )
            cv2.warpPerspective(
                work,
                Hk,
                (W, H),
                dst=warped,
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=border,
            )
            cv2.accumulate(warped, part)
        cv2.scaleAdd(part, float((tb - ta) / (n * exposure_s)), acc, dst=acc)
    if work is not img:
        acc = np.asarray(cv2.cvtColor(acc, cv2.COLOR_BGRA2BGR))
    tau = (np.concatenate(times) - t0) / exposure_s
    grid = NodeGrid.build(W, H, st.grid_px)
    mx, my = source_positions(model, t0, exposure_s, t_ref, grid.u, grid.v, tau)
    margin = np.minimum(np.minimum(mx, W - 1.0 - mx), np.minimum(my, H - 1.0 - my)).min(axis=0)
    valid = np.ascontiguousarray(grid.upsample(margin) >= 0)
    return RenderResult(
        acc, valid, tau, float(np.max(step / n_j)), "paper", np.concatenate(weights)
    )
