"""The camera–IMU time shift refined by the gyro's predicted streak templates, for the
template pass (:mod:`blurtrack.detect.gyro.gyropass`).

The scan (:mod:`blurtrack.detect.gyro.timeshift`) matches the first pass's measured *ends* with the
predicted ones. Where the frames hold saturated, touching streaks measured by the first pass
alone, its minimum lies off the truth: on ``hard`` seeds 1-3 by -1.56, +1.44 and -1.59 ms (with
the session's nominal calibration, and by 0.7-1.4 ms with the true one: the measured ends'
own bias), and the template pass, whose templates are the predicted curves, loses for it
(hard seed 2: recall 89.9 % at the scan's shift, 91.3 % at the true one).

Part of that is the readout: a rolling shutter's rows expose at ``t + readout * y / H``, so
a readout off by ``dr`` moves the time of a streak at row ``y`` by ``dr * y / H``, and one
shift can match only one row band (hard seeds 1-3: readouts off by -1.13, +0.60, -2.44 ms; the
template-best single shift off the truth by -0.80, +0.14, -1.42 ms, about half of that, the
frame's middle). Both are refined here, together.

The shift is the one whose predicted curves explain the light of isolated first-pass
streaks best: each streak's curve, predicted from its mid-exposure point at a trial shift, is
rendered as a template (:func:`blurtrack.detect.gyro.gyrocurve.curve_template`) and matched within
:data:`WINDOW_PX` of where it was predicted, by its correlation normalised over its support
*and halo* (light past a template's ends counts against it: a curve too long or too short,
too bent or not enough); the best placement's value, summed over the streaks, is the score of
the shift. Each streak is scored on the grid of trial shifts :data:`GRID_HALF_MS` about the
scan's in steps of :data:`GRID_STEP_MS` (the curves rendered once per trial); a streak at
row fraction ``u = y / H`` sees the shift ``m + dr * (u - 1/2)`` (``m`` the shift at the
frame's middle row), and ``(m, dr)`` is the best pair of a fine grid (:data:`FIT_STEP_MS`,
``dr`` within ``timeshift.readout_rel`` of the session's readout, :data:`READOUT_STEP_MS`) of the
streaks' scores interpolated between the trials by a Catmull-Rom spline. The readout is fitted
only for a rolling shutter (readout > 0) and streaks spread over the rows
(``timeshift.min_row_spread``). It runs only where the template pass will use the shift: on sessions
where the pass's gate lets one of the sampled frames through (those frames are decoded here
and again by the pass: ~10 ms each).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from blurtrack.detect.forkmap import fork_map
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.gyro.gyrocurve import curve_template, predict_curves
from blurtrack.detect.gyro.gyrogate import gate
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import FrameTiming
from blurtrack.errors import CoverageError

#: Frames sampled (spread over the covered ones) and streaks used per frame: the refinement's
#: budget (each sampled frame is decoded again, each streak rendered once per trial shift).
MAX_FRAMES = 6
MAX_STREAKS_PER_FRAME = 40
#: Trial shifts about the scan's (ms): ``-GRID_HALF_MS .. +GRID_HALF_MS`` in ``GRID_STEP_MS``
#: (the scan's minimum lies within 1.6 ms of the truth on ``hard``: twice that; a step well
#: under the 10-50 ms exposures, interpolated by the spline).
GRID_HALF_MS = 3.0
GRID_STEP_MS = 0.375
#: The fine grid of the fit: the middle row's shift (ms) and the readout's change (ms), the
#: latter within ``timeshift.readout_rel`` of the session's readout (a third and two thirds
#: of the trial step: the spline's resolution).
FIT_STEP_MS = 0.125
READOUT_STEP_MS = 0.25
#: A template is matched at placements up to this far (px) from its predicted position (the
#: scan's shift, off by <= 1.6 ms, moves a dot by <= 2-3 px on ``hard``).
WINDOW_PX = 3


@dataclass(frozen=True)
class ShiftRefinement:
    """``timeshift_s`` (t_imu = t_cam + shift) and ``readout_s``: the refined ones, or the
    scan's ``initial_s`` and the session's readout where ``status`` is not ``refined``; the
    trial ``grid_s`` (shifts of the scan's model), the streaks' summed ``score`` there and the
    streaks scored. ``status``: ``refined``, ``not needed`` (the gate lets no sampled frame
    through), ``too few streaks``, ``at the grid's edge`` (the best shift is the first or the
    last trial: the scan is too far off to refine), ``flat`` (no shift scores above another:
    the gyro does not tell them apart)."""

    timeshift_s: float
    readout_s: float
    initial_s: float
    grid_s: np.ndarray
    score: np.ndarray
    n_streaks: int
    status: str


def usable_streaks(
    fs: FrameStreaks,
    n: int = MAX_STREAKS_PER_FRAME,
    min_length_px: float = DetectParams().timeshift.refit_min_length_px,
) -> np.ndarray:
    """Indices of up to ``n`` streaks of a frame that are one dot each as far as the first pass
    can tell (not clipped by the border, merged or crossing; at least ``min_length_px``),
    spread over the frame's list."""
    if len(fs) == 0:
        return np.zeros(0, np.int64)
    f = fs.flags
    ok = np.flatnonzero(
        ~f["clipped"] & ~f["merged"] & ~f["crossing"] & (fs.length_px >= min_length_px)
    )
    if ok.size <= n:
        return ok
    return np.unique(ok[np.linspace(0, ok.size - 1, n).round().astype(np.int64)])


def streak_scores(
    smooth: np.ndarray,
    ref: np.ndarray,
    timing: FrameTiming,
    model: Any,
    deltas_s: np.ndarray,
    sigma_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Best correlations ``(G, n)`` with the smoothed frame ``smooth (H, W)`` of the curves
    predicted from mid-exposure points ``ref (N, 2)`` (frame px) at each trial shift
    ``deltas_s (G,)`` added to the model's, for the ``n`` curves whose template and window lie
    inside the frame at every shift, and those curves' indices ``(n,)``. ``sigma_px``: the
    templates' cross-section (the smoothed image's).

    A shift of the camera-IMU offset by ``delta`` is the model evaluated at camera times
    moved by ``delta`` (its own shift left as it is)."""
    img = np.asarray(smooth, np.float32)
    H, W = img.shape
    R = WINDOW_PX
    out = np.zeros((deltas_s.size, ref.shape[0]))
    ok = np.ones(ref.shape[0], bool)
    for g, d in enumerate(deltas_s):
        curves = predict_curves(model, ref, timing.t_s + float(d), timing.exposure_s)
        for j in np.flatnonzero(ok):
            tpl = curve_template(curves.pts[j], sigma_px, sigma_px, 1.0, None, False)
            x, y, w, h = tpl.box
            if x < R or y < R or x + w + R > W or y + h + R > H:
                ok[j] = False
                continue
            region = img[y - R : y + h + R, x - R : x + w + R]
            num = cv2.matchTemplate(region, tpl.smooth, cv2.TM_CCORR)
            den = cv2.matchTemplate(region * region, tpl.support + tpl.halo, cv2.TM_CCORR)
            lit = den > 0.0
            if not lit.any():
                ok[j] = False
                continue
            out[g, j] = float(np.max(num[lit] / np.sqrt(den[lit] * tpl.norm2)))
    keep = np.flatnonzero(ok)
    return out[:, keep], keep


def fit_shift_readout(
    grid_ms: np.ndarray, scores: np.ndarray, row_frac: np.ndarray, readout_max_ms: float
) -> tuple[float, float, bool]:
    """The middle row's shift ``m`` and the readout's change ``dr`` (ms) that maximise the
    summed scores, streak ``j`` (row fraction ``row_frac[j]``, its scores ``scores[:, j]`` on
    the uniform ``grid_ms``, a Catmull-Rom spline between) seeing the shift
    ``m + dr * (row_frac[j] - 1/2)``;
    ``|dr| <= readout_max_ms`` (0: the shift alone), every streak's shift inside the grid.
    Also whether the best lies where the grid ends (the grid does not hold the peak).

    >>> g = np.linspace(-3.0, 3.0, 17)
    >>> u = np.array([0.1, 0.5, 0.9])
    >>> sc = -((g[:, None] - (0.5 + 2.0 * (u - 0.5))) ** 2)  # m 0.5 ms, dr 2 ms
    >>> fit_shift_readout(g, sc, u, 3.0)
    (0.5, 2.0, False)
    """
    step, g0, g1 = float(grid_ms[1] - grid_ms[0]), float(grid_ms[0]), float(grid_ms[-1])
    m = np.arange(g0, g1 + 1e-9, FIT_STEP_MS)
    dr = (
        np.arange(-readout_max_ms, readout_max_ms + 1e-9, READOUT_STEP_MS)
        if readout_max_ms > 0
        else np.zeros(1)
    )
    if dr.size > 1:
        dr = dr - dr[np.argmin(np.abs(dr))]  # the grid holds dr = 0 exactly
    e = m[:, None, None] + dr[None, :, None] * (row_frac - 0.5)[None, None, :]
    inside = np.all((e >= g0 - 1e-9) & (e <= g1 + 1e-9), axis=2)
    pos = np.clip((e - g0) / step, 0.0, grid_ms.size - 1.0)
    i0 = np.minimum(np.floor(pos).astype(np.int64), grid_ms.size - 2)
    f = pos - i0
    # Catmull-Rom between the trials (exact for a parabola: the peak is not drawn to the
    # trials as by linear interpolation), the ends extended linearly.
    p = np.concatenate([2 * scores[:1] - scores[1:2], scores, 2 * scores[-1:] - scores[-2:-1]])
    col = np.arange(row_frac.size)
    p0, p1, p2, p3 = (p[i0 + k, col] for k in range(4))
    total = 0.5 * np.sum(
        2 * p1
        + (p2 - p0) * f
        + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f**2
        + (3 * p1 - p0 - 3 * p2 + p3) * f**3,
        axis=2,
    )
    total = np.where(inside, total, -np.inf)
    a, b = np.unravel_index(int(np.argmax(total)), total.shape)
    lo = float(e[a, b].min())
    hi = float(e[a, b].max())
    at_edge = lo <= g0 + step / 2 or hi >= g1 - step / 2
    return round(float(m[a]), 9), round(float(dr[b]), 9), bool(at_edge)


def refine_timeshift(
    read_smooth: Any,
    found: Sequence[FrameStreaks],
    timings: Sequence[FrameTiming],
    covered: Sequence[int],
    model: Any,
    params: DetectParams,
    workers: int = 1,
) -> ShiftRefinement:
    """The template-refined shift and readout (module text) about ``model``'s, from up to
    :data:`MAX_FRAMES` of the ``covered`` frames (positions in ``found``) that the template
    pass's gate lets through. ``read_smooth(k)``: frame ``k``'s image as stored (decoded only
    for the frames scored, in ``workers`` forked processes). The templates' cross-section is
    the session's median (as in the template pass)."""
    initial = float(model.calib.timeshift_cam_imu_s)
    readout = float(model.camera.readout_s)
    H = float(model.camera.height)
    grid_ms = np.arange(-GRID_HALF_MS, GRID_HALF_MS + 1e-9, GRID_STEP_MS)
    deltas = 1e-3 * grid_ms

    def result(status: str, score: np.ndarray | None = None, n: int = 0) -> ShiftRefinement:
        sc = np.zeros(deltas.size) if score is None else score
        return ShiftRefinement(initial, readout, initial, initial + deltas, sc, n, status)

    spread = np.linspace(0, len(covered) - 1, min(MAX_FRAMES, len(covered))).round()
    pick = [covered[int(i)] for i in np.unique(spread)] if covered else []
    through = [k for k in pick if gate(found[k], timings[k], model, params.gyro_pass) is not None]
    if not through:
        return result("not needed")
    min_len = params.timeshift.refit_min_length_px
    sel = {k: usable_streaks(found[k], min_length_px=min_len) for k in through}
    scored = [k for k in through if sel[k].size]
    if sum(sel[k].size for k in scored) < params.timeshift.refit_min_streaks:
        return result("too few streaks")
    sigma_px = float(np.median([found[k].sigma_c_px for k in covered]))

    def one(k: int) -> tuple[np.ndarray, np.ndarray]:
        prep = prepare_frame(
            read_smooth(k),
            params.smooth_sigma_px,
            params.hot_pixel_ratio,
            params.saturation_level,
            params.colour,
        )
        ref = found[k].time_mid[sel[k]]
        try:
            sc, keep = streak_scores(prep.smooth, ref, timings[k], model, deltas, sigma_px)
        except CoverageError:  # the model covers the frame at its shift, not at every trial
            return np.zeros((deltas.size, 0)), np.zeros(0)
        return sc, np.clip(ref[keep, 1], 0.0, H - 1.0) / H

    parts = list(fork_map(one, scored, workers))
    scores = np.concatenate([p[0] for p in parts], axis=1)
    rows = np.concatenate([p[1] for p in parts])
    total = scores.sum(axis=1)
    n = int(rows.size)
    if n < params.timeshift.refit_min_streaks:
        return result("too few streaks", total, n)
    if not float(total.max() - total.min()) > 1e-6 * max(float(total.max()), 1e-12):
        return result("flat", total, n)
    fit_readout = readout > 0.0 and float(np.std(rows)) >= params.timeshift.min_row_spread
    m, dr, at_edge = fit_shift_readout(
        grid_ms, scores, rows, params.timeshift.readout_rel * 1e3 * readout if fit_readout else 0.0
    )
    if at_edge:
        return result("at the grid's edge", total, n)
    # Row fraction u sees m + dr (u - 1/2) = shift + dr u: the shift is that of row 0.
    shift = initial + 1e-3 * (m - 0.5 * dr)
    return ShiftRefinement(
        shift, readout + 1e-3 * dr, initial, initial + deltas, total, n, "refined"
    )
