"""The gyro's predicted streak curves and templates rendered from them
(:mod:`blurtrack.detect.gyro.gyropass`).

A dot seen at pixel ``p`` at its row's mid-exposure draws, over its row's exposure, the curve
``warp(p, t_ref, t)``: the blur model (gyro, intrinsics, ``R_cam_imu``, time shift) predicts
it, with the rolling shutter (the row, hence the time, follows the dot: a fixed point, two
iterations). Light is proportional to time, so the curve sampled *uniformly in time* and
blurred by the frame's cross-section Gaussian is the streak's image, brightness profile
included: a dot that slows down and turns (a hairpin) is brighter at its tip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from blurtrack.detect.separation.templates import Template, finish
from blurtrack.geometry.orientation_grid import GRID_STEP_S, OrientationGrid

#: Grid step (s) of the predictions of a streak's two ends alone (the session calibration's
#: and the check's vectors, the streaks of many frames to a call, where a grid over every
#: frame at :data:`~blurtrack.geometry.orientation_grid.GRID_STEP_S` costs more than the
#: samples): within 0.03 px of the converged integration on a shaking model (streaks up to
#: 110 px), where the kernel in the detection models' 4 ms sub-steps misses by 0.15 px.
TWO_END_STEP_S = 1e-3

#: Samples per predicted curve (uniform in time).
CURVE_SAMPLES = 65
#: Rolling-shutter fixed-point iterations (the row of each sample moves its time).
SHUTTER_ITERATIONS = 2
#: A template's support: pixels above this fraction of its peak (before clipping).
SUPPORT_LEVEL = 0.08


@dataclass(frozen=True)
class Curves:
    """Predicted curves ``pts (N, S, 2)`` (frame px, uniform in time, start first) of points
    seen at ``ref (N, 2)`` at their rows' mid-exposure; ``arc`` and ``chord`` ``(N,)``."""

    pts: np.ndarray
    ref: np.ndarray

    @property
    def arc(self) -> np.ndarray:
        return np.asarray(np.sum(np.hypot(*np.diff(self.pts, axis=1).transpose(2, 0, 1)), axis=1))

    @property
    def chord(self) -> np.ndarray:
        return np.asarray(np.hypot(*(self.pts[:, -1] - self.pts[:, 0]).T))


def predict_curves(
    model: Any,
    ref: np.ndarray,
    frame_t_s: float | np.ndarray,
    exposure_s: float | np.ndarray,
    samples: int = CURVE_SAMPLES,
    *,
    step_s: float | None = None,
) -> Curves:
    """Curves of the dots seen at ``ref (N, 2)`` at their rows' mid-exposure. ``frame_t_s``,
    ``exposure_s``: the frame's (or ``(N,)``, one per dot: the streaks of many frames in one
    call). ``model``: a :class:`blurtrack.geometry.blur_model.BlurModel` covering the frames
    (:class:`~blurtrack.errors.CoverageError` otherwise). The tracks are read from the model's
    orientation grid over each frame's readout and exposure
    (:meth:`~blurtrack.geometry.blur_model.BlurModel.orientation_grid`, built once for the
    shutter iterations), of :data:`~blurtrack.geometry.orientation_grid.GRID_STEP_S` for
    curves, of :data:`TWO_END_STEP_S` for a streak's two ends alone (``samples`` 2), or of
    ``step_s`` where given."""
    cam = model.camera
    H = float(cam.height)
    ref = np.asarray(ref, float).reshape(-1, 2)
    n = ref.shape[0]
    if n == 0:
        return Curves(np.zeros((0, samples, 2)), ref)
    ft = np.broadcast_to(np.asarray(frame_t_s, float), (n,))[:, None]
    ex = np.broadcast_to(np.asarray(exposure_s, float), (n,))[:, None]
    tau = np.linspace(0.0, 1.0, samples)[None, :]
    row_t = ft[:, 0] + cam.readout_s * np.clip(ref[:, 1], 0, H - 1) / H
    t_ref = row_t + 0.5 * ex[:, 0]
    t = row_t[:, None] + ex * tau
    if step_s is None:
        step_s = TWO_END_STEP_S if samples <= 2 else GRID_STEP_S
    track = _tracks(model, ft[:, 0], ex[:, 0], step_s)
    seen = track.directions(ref, t_ref)  # the same points at every iteration
    for _ in range(SHUTTER_ITERATIONS + 1):
        pos = track.at(seen, t)
        t = ft + cam.readout_s * np.clip(pos[..., 1], 0, H - 1) / H + ex * tau
    return Curves(np.asarray(pos, float), ref)


@dataclass(frozen=True)
class _Tracks:
    """Point tracks of the dots of frames read from the model's orientation grid over each
    frame's window (``window (N,)``, one per dot): :meth:`directions` once, then the positions
    at any times :meth:`at`."""

    grid: OrientationGrid
    window: np.ndarray
    intrinsics: tuple[float, float, float, float]
    dist: tuple[float, ...]

    def directions(
        self, ref: np.ndarray, t_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The directions of the dots seen at ``ref (N, 2)`` at ``t_ref (N,)``."""
        return self.grid.directions(ref, t_ref, self.window, self.intrinsics, self.dist)

    def at(self, seen: tuple[np.ndarray, np.ndarray, np.ndarray], t: np.ndarray) -> np.ndarray:
        """``(N, S, 2)`` the positions of the :meth:`directions` ``seen`` at times ``t``."""
        return self.grid.track_directions(seen, t, self.window, self.intrinsics, self.dist)


def _tracks(model: Any, ft: np.ndarray, ex: np.ndarray, step_s: float) -> _Tracks:
    """Point tracks of the dots of frames starting at ``ft (N,)`` with exposures ``ex (N,)``,
    read from the model's orientation grid over each frame's window ``[ft, ft + readout +
    exposure]`` (every row's times and mid-exposure lie in it)."""
    starts, window = np.unique(ft, return_inverse=True)
    ends = np.full(starts.shape, -np.inf)
    np.maximum.at(ends, window, ft + model.camera.readout_s + ex)
    grid = model.orientation_grid(starts, ends, step_s)
    cam = model.camera
    return _Tracks(grid, window, cam.intrinsics, cam.dist)


def similar_curve(pts: np.ndarray, z: complex) -> np.ndarray:
    """``pts (S, 2)`` rotated and scaled by ``z`` about its mean (its light's centroid)."""
    c = pts.mean(axis=0)
    w = (pts[:, 0] - c[0]) + 1j * (pts[:, 1] - c[1])
    w = w * z
    return np.stack([w.real + c[0], w.imag + c[1]], axis=1)


def _splat(pts: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """The curve ``pts`` (uniform in time, unit total light) as bilinear splats (variance
    ~1/6 px^2 per axis) on the grid ``[x0, x0 + w) x [y0, y0 + h)``, ``(h, w)`` float64."""
    u, v = pts[:, 0] - x0, pts[:, 1] - y0
    iu, iv = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - iu, v - iv
    gu, gv = 1.0 - fu, 1.0 - fv
    # The four corners of every sample, accumulated in one pass (in the order of four
    # sequential ``np.add.at``: the same sums).
    cu = np.concatenate([iu, iu + 1, iu, iu + 1])
    cv = np.concatenate([iv, iv, iv + 1, iv + 1])
    k = np.concatenate([gu * gv, fu * gv, gu * fv, fu * fv]) * (1.0 / len(pts))
    if iu.min() >= 0 and iu.max() + 1 < w and iv.min() >= 0 and iv.max() + 1 < h:
        flat = cv * w + cu  # every corner on the grid (a template's own box): no selection
    else:
        ok = (cu >= 0) & (cu < w) & (cv >= 0) & (cv < h)
        flat, k = cv[ok] * w + cu[ok], k[ok]
    img = np.bincount(flat, k, h * w).astype(np.float64, copy=False)
    return img.reshape(h, w)


def _blurred(splat: np.ndarray, sigma: float) -> np.ndarray:
    """Splats (:func:`_splat`) blurred to a Gaussian of ``sigma`` px in all."""
    s = float(np.sqrt(max(sigma * sigma - 1.0 / 6.0, 0.09)))
    return np.asarray(cv2.GaussianBlur(splat, (0, 0), s, borderType=cv2.BORDER_CONSTANT))


def curve_template(
    pts: np.ndarray,
    sigma_smooth: float,
    sigma_raw: float,
    light: float,
    ceiling: float | None,
    with_raw: bool = True,
) -> Template:
    """A :class:`~blurtrack.detect.separation.templates.Template` of the predicted curve ``pts``
    (frame px): its smoothed image holds ``light`` (the light of a typical dot of the frame, in the
    smoothed image's units, summed over pixels) and is clipped at ``ceiling`` (the
    saturation level: a saturated tip is flat in the image too); ``points`` is the curve
    itself, the coarse centre line that the measurement refines. ``with_raw=False`` leaves
    the unsmoothed image zero (a template only to be correlated: half the work)."""
    pad = int(np.ceil(3.0 * max(sigma_smooth, sigma_raw))) + 2
    lo, hi = pts.min(axis=0).tolist(), pts.max(axis=0).tolist()
    x0, y0 = math.floor(lo[0]) - pad, math.floor(lo[1]) - pad
    x1, y1 = math.ceil(hi[0]) + pad + 1, math.ceil(hi[1]) + pad + 1
    w, h = x1 - x0, y1 - y0
    splat = _splat(pts, x0, y0, w, h)
    sm = _blurred(splat, sigma_smooth)
    sup = sm > SUPPORT_LEVEL * sm.max()
    vals = sm[sup]
    tot = float(np.sum(vals))
    a = light / max(tot, 1e-12)
    if ceiling is not None:
        # The amplitude whose clipped template still holds ``light`` (a few fixed-point steps:
        # the clipped sum is increasing and concave in the amplitude).
        buf = np.empty_like(vals)
        for _ in range(6):
            got = float(np.minimum(np.multiply(a, vals, out=buf), ceiling, out=buf).sum())
            if got <= 0 or abs(got - light) < 1e-3 * light:
                break
            a *= light / got
            a = min(a, 50.0 * light / max(tot, 1e-12))

    def scaled(img: np.ndarray) -> np.ndarray:
        out = a * img
        if ceiling is not None:
            np.minimum(out, ceiling, out=out)
        return np.where(sup, out, 0.0).astype(np.float32)

    raw = scaled(_blurred(splat, sigma_raw)) if with_raw else None
    return finish((x0, y0, w, h), scaled(sm), raw, sup.astype(np.float32), np.asarray(pts, float))


def turn_index(pts: np.ndarray) -> int:
    """The sample where a hairpin turns: the farthest from the middle of its two ends."""
    mid = 0.5 * (pts[0] + pts[-1])
    return int(np.argmax(np.hypot(*(pts - mid).T)))


def arm_templates(
    tpl: Template, sigma_smooth: float, sigma_raw: float
) -> tuple[Template, Template]:
    """The two arms of a hairpin template (``tpl.points`` start to turn, turn to end): its
    light shared in proportion to each arm's unclipped rendering, so the two add up to
    ``tpl``; each arm's ``points`` run from the turn outwards (their far ends are the streak's
    start and end)."""
    pts = tpl.points
    k = turn_index(pts)
    x, y, w, h = tpl.box
    out = []
    parts = (pts[: k + 1][::-1], pts[k:])
    splats = [_splat(q, x, y, w, h) for q in parts]
    share = [_blurred(q, sigma_smooth) * len(p) for q, p in zip(splats, parts, strict=True)]
    share_r = [_blurred(q, sigma_raw) * len(p) for q, p in zip(splats, parts, strict=True)]
    tot = share[0] + share[1] + 1e-30
    tot_r = share_r[0] + share_r[1] + 1e-30
    for q, s, sr in zip(parts, share, share_r, strict=True):
        f = (s / tot).astype(np.float32)
        fr = (sr / tot_r).astype(np.float32)
        sm = tpl.smooth * f
        out.append(
            Template(
                tpl.box,
                sm,
                tpl.raw * fr,
                tpl.support,
                tpl.halo,
                float(np.sum(sm * sm)),
                np.asarray(q, float),
                tpl.area,
            )
        )
    return out[0], out[1]
