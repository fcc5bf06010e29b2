"""Segmentation: threshold the smoothed frame, label streaks, and order their pixels.

Most streaks are single-valued over their principal axis (straight or gently curved). For all
of them at once, :func:`axis_polylines` bins the component pixels along that axis and takes
weighted centroids per 1-px bin, giving an ordered coarse centre line with numpy reductions
instead of per-pixel loops. Components that are not single-valued (S-curves folding back,
loops, crossings) are reported as ``folded`` and handed to :mod:`blurtrack.detect.skeleton`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.errors import DetectionError


@dataclass(frozen=True)
class Components:
    """Connected components of the thresholded frame.

    - ``labels``: ``(H, W)`` int32 label image (0 = background).
    - ``ys``, ``xs``: coordinates of all labelled pixels (any component).
    - ``ids``: ``(N,)`` labels kept (large and bright enough).
    - ``boxes``: ``(N, 4)`` int ``x, y, w, h`` bounding boxes.
    - ``peaks``: ``(N,)`` peak of the smoothed signal per component.
    - ``areas``: ``(N,)`` pixel counts.
    """

    labels: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    ids: np.ndarray
    boxes: np.ndarray
    peaks: np.ndarray
    areas: np.ndarray


def find_components(
    smooth: np.ndarray, threshold: float, min_area_px: int, max_streaks: int
) -> Components:
    """Threshold ``smooth`` (background subtracted, full-scale units); label 8-connected blobs."""
    mask = (smooth > threshold).view(np.uint8)
    # Labels without OpenCV's statistics pass (several times slower than the labelling); the
    # statistics come from the pixel list, which the centre lines need anyway.
    n, labels = cv2.connectedComponentsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_SAUF)
    nz = cv2.findNonZero(mask)  # much faster than np.nonzero on a full frame
    nz = np.zeros((0, 2), np.int64) if nz is None else nz.reshape(-1, 2).astype(np.int64)
    xs, ys = nz[:, 0], nz[:, 1]
    lab = labels[ys, xs]
    areas = np.bincount(lab, minlength=n)
    ids = np.flatnonzero(areas >= min_area_px)
    ids = ids[ids > 0].astype(np.int32)
    if ids.size > max_streaks:
        raise DetectionError(
            f"{ids.size} bright components in one frame (limit {max_streaks}): "
            "not a laser-dot frame"
        )
    lo = np.full((n, 2), np.iinfo(np.int64).max)
    hi = np.full((n, 2), -1)
    np.minimum.at(lo, lab, nz)
    np.maximum.at(hi, lab, nz)
    best = np.zeros(n, dtype=np.float64)
    np.maximum.at(best, lab, smooth[ys, xs])
    boxes = np.concatenate([lo[ids], hi[ids] - lo[ids] + 1], axis=1)
    peaks = best[ids]
    return Components(
        labels=labels,
        ys=ys,
        xs=xs,
        ids=ids,
        boxes=boxes,
        peaks=peaks,
        areas=areas[ids],
    )


def axis_polylines(
    smooth: np.ndarray, comps: Components, sigma_px: float
) -> tuple[list[np.ndarray], np.ndarray]:
    """Coarse ordered centre lines of all components by binning along their principal axes.

    Args:
        smooth: ``(H, W)`` smoothed signal (weights).
        comps: the components.
        sigma_px: expected cross-section sigma of a streak in ``smooth``.
    Returns:
        ``(polylines, folded)``: per component an ``(n, 2)`` float array of (x, y) points,
        ordered along the principal axis (a single point for a round spot), and a bool ``(N,)``
        array, True where the component is not single-valued over its axis (its polyline must
        then come from the skeleton tracer instead).
    """
    N = comps.ids.size
    if N == 0:
        return [], np.zeros(0, bool)
    lut = np.zeros(comps.labels.max() + 1, dtype=np.int64)
    lut[:] = -1
    lut[comps.ids] = np.arange(N)
    ys, xs = comps.ys, comps.xs
    idx = lut[comps.labels[ys, xs]]
    sel = idx >= 0
    ys, xs, idx = ys[sel], xs[sel], idx[sel]
    w = np.maximum(smooth[ys, xs].astype(np.float64), 1e-12)
    x = xs.astype(np.float64)
    y = ys.astype(np.float64)
    sw = np.bincount(idx, w, N)
    mx = np.bincount(idx, w * x, N) / sw
    my = np.bincount(idx, w * y, N) / sw
    dx = x - mx[idx]
    dy = y - my[idx]
    cxx = np.bincount(idx, w * dx * dx, N) / sw
    cyy = np.bincount(idx, w * dy * dy, N) / sw
    cxy = np.bincount(idx, w * dx * dy, N) / sw
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # principal axis angle per component
    ux, uy = np.cos(theta), np.sin(theta)
    s = dx * ux[idx] + dy * uy[idx]
    t = -dx * uy[idx] + dy * ux[idx]
    smin = np.full(N, np.inf)
    smax = np.full(N, -np.inf)
    np.minimum.at(smin, idx, s)
    np.maximum.at(smax, idx, s)
    nbins = (np.floor(smax - smin) + 1).astype(np.int64)
    offsets = np.concatenate(([0], np.cumsum(nbins)))
    gb = offsets[idx] + np.floor(s - smin[idx]).astype(np.int64)
    total = int(offsets[-1])
    bw = np.bincount(gb, w, total)
    with np.errstate(invalid="ignore", divide="ignore"):
        bs = np.bincount(gb, w * s, total) / bw
        bt = np.bincount(gb, w * t, total) / bw
        btt = np.bincount(gb, w * t * t, total) / bw - bt * bt
    # Single-valued test: no empty bin, and no well-filled bin much wider than a straight
    # streak cut obliquely (a 60 degree slope doubles the width).
    bin_label = np.repeat(np.arange(N), nbins)
    med_w = np.zeros(N)
    np.maximum.at(med_w, bin_label, bw)
    strong = bw > 0.25 * med_w[bin_label]
    wide = strong & (btt > (2.0 * sigma_px) ** 2)
    empty = bw <= 0
    folded = np.zeros(N, bool)
    np.logical_or.at(folded, bin_label, wide | empty)
    polylines: list[np.ndarray] = []
    for i in range(N):
        a, b = offsets[i], offsets[i + 1]
        ss, tt = bs[a:b], bt[a:b]
        px = mx[i] + ss * ux[i] - tt * uy[i]
        py = my[i] + ss * uy[i] + tt * ux[i]
        polylines.append(np.stack([px, py], axis=1))
    return polylines, folded
