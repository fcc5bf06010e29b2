"""The frame context: one frame's arrays and per-frame constants, as every detection stage reads
them (:func:`blurtrack.detect.frame.detect_frame` builds it once per frame, the gyro-template
pass once per frame it refines)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from blurtrack.detect.image import PreparedFrame, prepare_frame
from blurtrack.detect.lines.segment import Components, drop_artefacts, find_components
from blurtrack.detect.params import DetectParams


def near_border(a: np.ndarray, b: np.ndarray, W: int, H: int, m_px: float) -> np.ndarray:
    """``(N,)``: an end within ``m_px`` of the border of a ``W`` x ``H`` px frame."""
    e = np.stack([a, b], axis=1)
    near = (e[..., 0] < m_px) | (e[..., 0] > W - 1 - m_px) | (e[..., 1] < m_px)
    return np.asarray((near | (e[..., 1] > H - 1 - m_px)).any(axis=1))


@dataclass(frozen=True)
class FrameContext:
    """One frame as the detection stages see it. Intensities are in full-scale units (1.0 =
    white, background subtracted), coordinates in px of the frame (x right, y down).

    - ``smooth``: ``(H, W)`` float32, the signal after the Gaussian pre-smoothing
      (``params.smooth_sigma_px``): the image that lines are traced and measured on.
    - ``signal``: ``(H, W)`` float32, the unsmoothed signal (hot pixels removed): the profiles
      of saturated streaks are taken there.
    - ``saturation``: the saturation level in ``signal`` units.
    - ``sat_comp``: ``(C,)`` bool, which components hold saturated pixels; None when no pixel
      of the frame is saturated.
    - ``comps``: the frame's ``C`` connected components above ``threshold`` (artefacts
      dropped).
    - ``threshold``: the segmentation threshold on ``smooth`` (full-scale units).
    - ``noise_smooth``: the noise sigma of ``smooth`` (full-scale units).
    - ``params``: the detection parameters.

    Stages that measure on images of their own (a mosaic of separated streaks, a crop around
    a fragment) take :meth:`on` them: the same frame's constants with other ``smooth`` and
    ``signal`` (then ``shape`` is theirs).
    """

    smooth: np.ndarray
    signal: np.ndarray
    saturation: float
    sat_comp: np.ndarray | None
    comps: Components
    threshold: float
    noise_smooth: float
    params: DetectParams

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the images (px)."""
        H, W = self.smooth.shape
        return int(H), int(W)

    @property
    def smooth_sigma_px(self) -> float:
        """The pre-smoothing sigma (px)."""
        return self.params.smooth_sigma_px

    def on(self, smooth: np.ndarray, signal: np.ndarray) -> FrameContext:
        """The same frame's constants with other images to measure on (same units)."""
        return replace(self, smooth=smooth, signal=signal)

    def clipped(self, end_a: np.ndarray, end_b: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: streaks with an end within ``params.border_margin_px`` of the
        border (``end_a``, ``end_b``: ``(N, 2)`` px)."""
        H, W = self.shape
        return near_border(end_a, end_b, W, H, self.params.border_margin_px)

    def merged(self, width_px: np.ndarray, sigma_c_px: float) -> np.ndarray:
        """``(N,)`` bool: streaks wider than ``params.quality.merged_width`` times the
        cross-section sigma ``sigma_c_px`` (``width_px``: ``(N,)``, NaN where not measured)."""
        limit = self.params.quality.merged_width * sigma_c_px
        return np.isfinite(width_px) & (width_px > limit)


def frame_context(prep: PreparedFrame, params: DetectParams) -> FrameContext:
    """Segment a prepared frame: threshold, components, artefacts dropped, which components
    are saturated."""
    p = params
    threshold = max(p.threshold_snr * prep.noise_smooth, p.min_threshold)
    comps = find_components(prep.smooth, threshold, p.min_area_px, p.max_streaks)
    comps = drop_artefacts(comps, p.artefact_ratio, p.artefact_gap_px)
    sat_comp = None
    if prep.saturated.any():
        sat_comp = np.zeros(0, bool)
        if comps.ids.size:  # from the pixel lists: a saturated pixel lies in a component
            sat_comp = np.maximum.reduceat(prep.saturated[comps.ys, comps.xs], comps.starts)
    return FrameContext(
        smooth=prep.smooth,
        signal=prep.signal,
        saturation=prep.saturation,
        sat_comp=sat_comp,
        comps=comps,
        threshold=threshold,
        noise_smooth=prep.noise_smooth,
        params=p,
    )


def prepare_and_segment(
    image: np.ndarray, params: DetectParams
) -> tuple[PreparedFrame, FrameContext]:
    """A frame as stored (``(H, W)`` or ``(H, W, 3|4)``, uint8/uint16) prepared as detection
    prepares it (:func:`blurtrack.detect.image.prepare_frame` with ``params``' smoothing,
    hot-pixel ratio, saturation level and colour) and its :func:`frame_context`."""
    p = params
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level, p.colour)
    return prep, frame_context(prep, p)
