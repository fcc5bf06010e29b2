"""Segmentation: threshold the smoothed frame, label streaks, and order their pixels.

Most streaks are single-valued over their principal axis (straight or gently curved). For all
of them at once, :func:`axis_polylines` bins the component pixels along that axis and takes
weighted centroids per 1-px bin, giving an ordered coarse centre line with numpy reductions
instead of per-pixel loops. Components that are not single-valued (S-curves folding back,
loops, crossings) are reported as ``folded`` and handed to :mod:`blurtrack.detect.lines.skeleton`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.detect.lines.ragged import split_at
from blurtrack.errors import DetectionError


@dataclass(frozen=True)
class Components:
    """Connected components of the thresholded frame.

    - ``labels``: ``(H, W)`` uint16 (int32 for frames with more than 65535 blobs) label image
      (0 = background).
    - ``ys``, ``xs``: coordinates of the kept components' pixels, grouped by component;
      component ``i`` owns ``starts[i] : starts[i] + areas[i]``.
    - ``ids``: ``(N,)`` labels kept (large and bright enough).
    - ``boxes``: ``(N, 4)`` int ``x, y, w, h`` bounding boxes.
    - ``peaks``: ``(N,)`` peak of the smoothed signal per component.
    - ``areas``: ``(N,)`` pixel counts.
    - ``values``: the smoothed signal at every pixel of ``ys``, ``xs`` (float64).
    """

    labels: np.ndarray
    ys: np.ndarray
    xs: np.ndarray
    ids: np.ndarray
    starts: np.ndarray
    boxes: np.ndarray
    peaks: np.ndarray
    areas: np.ndarray
    values: np.ndarray


def find_components(
    smooth: np.ndarray, threshold: float, min_area_px: int, max_streaks: int
) -> Components:
    """Threshold ``smooth`` (background subtracted, full-scale units); label 8-connected blobs."""
    mask = (smooth > threshold).view(np.uint8)
    # Labels without OpenCV's statistics pass (several times slower than the labelling); the
    # statistics come from the pixel list, which the centre lines need anyway.
    # 16-bit labels halve the memory traffic; OpenCV raises on label overflow.
    try:
        n, labels = cv2.connectedComponentsWithAlgorithm(mask, 8, cv2.CV_16U, cv2.CCL_SPAGHETTI)
    except cv2.error:
        n, labels = cv2.connectedComponentsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_SPAGHETTI)
    nz = cv2.findNonZero(mask)  # much faster than np.nonzero on a full frame
    nz = np.zeros((0, 2), np.int32) if nz is None else nz.reshape(-1, 2)
    W = mask.shape[1]
    flat_idx = nz[:, 1].astype(np.intp) * W + nz[:, 0]
    lab = labels.ravel()[flat_idx]  # 1-D gathers: faster than 2-D indexing
    areas = np.bincount(lab, minlength=n)
    keep_label = areas >= min_area_px
    keep_label[0] = False
    ids = np.flatnonzero(keep_label).astype(np.int32)
    if ids.size > max_streaks:
        raise DetectionError(
            f"{ids.size} bright components in one frame (limit {max_streaks}): "
            "not a laser-dot frame"
        )
    # Pixels of kept components, grouped by component (per-component reductions then run
    # as reduceat over contiguous runs instead of slow unbuffered ufunc.at calls). Labels
    # are 16-bit in practice, which numpy sorts stably by radix.
    sel = np.flatnonzero(keep_label[lab])
    order = sel[np.argsort(lab[sel], kind="stable")]
    # Each (x, y) int32 pair gathered as one int64: one 1-D gather instead of a 2-D one.
    pairs = np.ascontiguousarray(nz).view(np.int64).ravel()[order]
    xs, ys = np.ascontiguousarray(pairs.view(np.int32).reshape(-1, 2).T)
    starts = np.concatenate(([0], np.cumsum(areas[ids])[:-1])).astype(np.int64)
    values = smooth.ravel()[flat_idx[order]].astype(np.float64)
    if ids.size:
        x0, x1 = np.minimum.reduceat(xs, starts), np.maximum.reduceat(xs, starts)
        y0, y1 = np.minimum.reduceat(ys, starts), np.maximum.reduceat(ys, starts)
        peaks = np.maximum.reduceat(values, starts)
    else:
        x0 = x1 = y0 = y1 = np.zeros(0, np.int64)
        peaks = np.zeros(0)
    return Components(
        labels=labels,
        ys=ys,
        xs=xs,
        ids=ids,
        starts=starts,
        boxes=np.stack([x0, y0, x1 - x0 + 1, y1 - y0 + 1], axis=1),
        peaks=peaks,
        areas=areas[ids],
        values=values,
    )


def drop_artefacts(comps: Components, ratio: float, gap_px: int) -> Components:
    """``comps`` without the faint artefacts of bright neighbours.

    JPEG ringing, demosaicing and blooming leave faint blobs next to bright streaks, a few
    per cent of their peak: a component whose peak is below ``ratio`` times the peak of
    another component whose bounding box is within ``gap_px`` of its own is dropped."""
    N = comps.ids.size
    if N < 2 or ratio <= 0:
        return comps
    x0, y0, w, h = comps.boxes.T.astype(np.int64)
    x1, y1 = x0 + w, y0 + h
    # Only components that some neighbour outshines by 1 / ratio can go: test those alone.
    weak = np.flatnonzero(comps.peaks < ratio * comps.peaks.max())
    if weak.size == 0:
        return comps
    gx = np.maximum(x0[weak, None] - x1[None, :], x0[None, :] - x1[weak, None])
    gy = np.maximum(y0[weak, None] - y1[None, :], y0[None, :] - y1[weak, None])
    close = (np.maximum(gx, gy) <= gap_px) & (
        comps.peaks[None, :] * ratio > comps.peaks[weak, None]
    )
    drop = weak[close.any(axis=1)]
    if drop.size == 0:
        return comps
    keep = np.setdiff1d(np.arange(N), drop)
    return subset(comps, keep)


def subset(comps: Components, keep: np.ndarray) -> Components:
    """The components ``keep`` (indices, increasing) of ``comps`` (same label image)."""
    areas = comps.areas[keep]
    starts = np.concatenate(([0], np.cumsum(areas)[:-1])).astype(np.int64)
    pix = np.repeat(comps.starts[keep] - starts, areas) + np.arange(int(areas.sum()))
    return Components(
        labels=comps.labels,
        ys=comps.ys[pix],
        xs=comps.xs[pix],
        ids=comps.ids[keep],
        starts=starts,
        boxes=comps.boxes[keep],
        peaks=comps.peaks[keep],
        areas=areas,
        values=comps.values[pix],
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
    ys, xs, st = comps.ys, comps.xs, comps.starts
    idx = np.repeat(np.arange(N), comps.areas)
    w = np.maximum(comps.values, 1e-12)
    x = xs.astype(np.float64)
    y = ys.astype(np.float64)
    sw = np.add.reduceat(w, st)
    mx = np.add.reduceat(w * x, st) / sw
    my = np.add.reduceat(w * y, st) / sw
    dx = x - mx[idx]
    dy = y - my[idx]
    cxx = np.add.reduceat(w * dx * dx, st) / sw
    cyy = np.add.reduceat(w * dy * dy, st) / sw
    cxy = np.add.reduceat(w * dx * dy, st) / sw
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # principal axis angle per component
    ux, uy = np.cos(theta), np.sin(theta)
    s = dx * ux[idx] + dy * uy[idx]
    t = -dx * uy[idx] + dy * ux[idx]
    smin = np.minimum.reduceat(s, st)
    smax = np.maximum.reduceat(s, st)
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
    max_w = np.maximum.reduceat(bw, offsets[:-1])
    strong = bw > 0.25 * max_w[bin_label]
    bad = (strong & (btt > (2.0 * sigma_px) ** 2)) | (bw <= 0)
    folded = np.maximum.reduceat(bad.astype(np.int8), offsets[:-1]) > 0
    px = mx[bin_label] + bs * ux[bin_label] - bt * uy[bin_label]
    py = my[bin_label] + bs * uy[bin_label] + bt * ux[bin_label]
    polylines = split_at(np.stack([px, py], axis=1), offsets[1:-1])
    return polylines, folded
