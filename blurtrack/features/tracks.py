"""Feature tracks between consecutive frames of an ordinary (natural-scene) video.

For each frame pair ``(i, i + 1)``: Shi–Tomasi corners in frame ``i`` (OpenCV
``goodFeaturesToTrack``; optionally on the frame downscaled, ``TrackParams.corner_downscale``),
tracked into frame ``i + 1`` by pyramidal Lucas–Kanade (``calcOpticalFlowPyrLK``) and back
again; a point is kept when the backward track returns within ``fb_max_px`` of where it
started (the forward–backward check rejects occlusions, repeated texture and blur-smeared
corners) and both ends lie inside the image by ``border_px``.

In a motion-blurred frame a tracked point sits where the blurred patch's light is centred: to
first order the scene point's position at the middle of its row's exposure. A point at pixel
``(x, y)`` of frame ``i`` is therefore dated ``t_i + readout · y / H + exposure_i / 2``
(DESIGN's rolling-shutter row times); :mod:`calib.natural.pipeline` builds the inter-frame
residual from that. Pixels follow DESIGN (``(0, 0)`` is the centre of the top-left pixel), as
OpenCV's do.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError


class FeatureTrackError(BlurTrackError):
    """Frames cannot be tracked (too few, unreadable, or nothing to track)."""


@dataclass(frozen=True)
class TrackParams:
    """Corner detection and Lucas–Kanade settings (pixels at the frame's resolution)."""

    max_corners: int = 400
    quality: float = 0.01
    min_distance_px: float = 10.0
    block_size: int = 7
    window_px: int = 21
    levels: int = 5
    fb_max_px: float = 0.5
    border_px: float = 4.0
    #: Frames whose longer side exceeds this are tracked downscaled (area averaging) and the
    #: points scaled back: strong blur leaves no detail finer than that, and the pyramid then
    #: reaches inter-frame motions of a few hundred pixels (DeepGyro's 1080p frames move
    #: ~220 px between frames).
    max_side_px: int = 1280
    #: Corners are looked for on the frame area-averaged by this integer factor (1: at full
    #: resolution), ``min_distance_px`` and ``block_size`` scaled with it, and tracked at full
    #: resolution. At 720p ``goodFeaturesToTrack`` takes 17 ms per frame at full resolution,
    #: 1.8 ms at half (2), and a natural calibration ~20 % less CPU, but on 10 seeds the half
    #: resolution's corners lost one cy and one rotation target (docs/journal/natural.md,
    #: "Corners at half resolution"), so full resolution stays the default.
    corner_downscale: int = 1
    #: Rectangles ``(x0, y0, x1, y1)`` (px, the frame's resolution) whose tracks are dropped
    #: (either end inside): parts of the image that do not show the static scene, e.g. a
    #: dashboard rigid with the camera (``blurtrack calibrate --mask``).
    exclude_px: tuple[tuple[float, float, float, float], ...] = ()

    def __post_init__(self) -> None:
        for r in self.exclude_px:
            if len(r) != 4 or not all(np.isfinite(r)) or not (r[2] > r[0] and r[3] > r[1]):
                raise FeatureTrackError(
                    f"a masked rectangle is x0,y0,x1,y1 with x1 > x0 and y1 > y0, got {r}"
                )
        if not 8 <= self.max_corners <= 20000:
            raise FeatureTrackError(f"max_corners must be in [8, 20000], got {self.max_corners}")
        if not 0 < self.quality < 1:
            raise FeatureTrackError(f"quality must be in (0, 1), got {self.quality}")
        if self.window_px < 5 or self.window_px % 2 == 0:
            raise FeatureTrackError(f"window_px must be odd and >= 5, got {self.window_px}")
        if not 0 <= self.levels <= 6:
            raise FeatureTrackError(f"levels must be in [0, 6], got {self.levels}")
        if not 1 <= self.corner_downscale <= 8:
            raise FeatureTrackError(
                f"corner_downscale must be in [1, 8], got {self.corner_downscale}"
            )
        if self.max_side_px < 64:
            raise FeatureTrackError(f"max_side_px must be >= 64, got {self.max_side_px}")
        if not self.fb_max_px > 0 or self.min_distance_px < 1 or self.border_px < 0:
            raise FeatureTrackError("fb_max_px must be positive, min_distance_px >= 1")


@dataclass(frozen=True)
class FeatureTracks:
    """Matched points of consecutive frames (one entry per tracked point).

    Attributes:
        frame_a, frame_b: ``(N,)`` frame indices (``frame_b = frame_a + 1``).
        pts_a, pts_b: ``(N, 2)`` pixels of the same scene point in the two frames.
        fb_error_px: ``(N,)`` forward–backward distance of each track.
        n_frames: frames looked at; ``per_pair``: points kept per frame pair ``(n_frames-1,)``.
    """

    frame_a: np.ndarray
    frame_b: np.ndarray
    pts_a: np.ndarray
    pts_b: np.ndarray
    fb_error_px: np.ndarray
    n_frames: int
    per_pair: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.frame_a).size
        for name in ("pts_a", "pts_b"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n, 2) or not np.all(np.isfinite(a)):
                raise FeatureTrackError(f"feature tracks: {name} must be finite (N, 2)")
            object.__setattr__(self, name, a)
        for name in ("frame_a", "frame_b"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), np.int64).reshape(-1))
        object.__setattr__(self, "fb_error_px", np.asarray(self.fb_error_px, float).reshape(-1))
        if self.frame_b.shape != (n,) or self.fb_error_px.shape != (n,):
            raise FeatureTrackError("feature tracks: per-point arrays differ in length")

    def __len__(self) -> int:
        return int(self.frame_a.size)

    @property
    def displacement_px(self) -> np.ndarray:
        return np.linalg.norm(self.pts_b - self.pts_a, axis=1)


def to_gray8(image: np.ndarray) -> np.ndarray:
    """A frame as 8-bit gray: BGR(A) converted, 16-bit scaled by its own 99.9th percentile."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2:
        raise FeatureTrackError(f"a frame must be gray or BGR, got shape {img.shape}")
    if img.dtype == np.uint8:
        return img
    f = img.astype(np.float32)
    top = float(np.percentile(f, 99.9)) or 1.0
    return np.clip(f * (255.0 / top), 0, 255).astype(np.uint8)


def track_pair(
    img_a: np.ndarray, img_b: np.ndarray, params: TrackParams = TrackParams()
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners of ``img_a`` tracked into ``img_b`` (both 8-bit gray, same size).

    Returns ``pts_a (M, 2)``, ``pts_b (M, 2)`` and the forward–backward errors ``(M,)`` of the
    points that pass the check, in ``img_a``'s pixels (see ``TrackParams.max_side_px``).
    """
    if img_a.shape != img_b.shape:
        raise FeatureTrackError(f"frames differ in size: {img_a.shape} and {img_b.shape}")
    k = params.max_side_px / max(img_a.shape)
    if k < 1:
        size = (round(img_a.shape[1] * k), round(img_a.shape[0] * k))
        ka, kb = size[0] / img_a.shape[1], size[1] / img_a.shape[0]
        small = [cv2.resize(i, size, interpolation=cv2.INTER_AREA) for i in (img_a, img_b)]
        a, b, e = _track(small[0], small[1], params)
        # Pixel centres: x_full + 0.5 = (x_small + 0.5) / k.
        back = np.array([1 / ka, 1 / kb])
        a, b, e = (a + 0.5) * back - 0.5, (b + 0.5) * back - 0.5, e * float(back.mean())
    else:
        a, b, e = _track(img_a, img_b, params)
    if not params.exclude_px:
        return a, b, e
    keep = ~(in_mask(a, params.exclude_px) | in_mask(b, params.exclude_px))
    return a[keep], b[keep], e[keep]


def in_mask(pts: np.ndarray, rects: tuple[tuple[float, float, float, float], ...]) -> np.ndarray:
    """``(N,)`` whether each point ``(N, 2)`` (px) lies inside one of the rectangles
    ``(x0, y0, x1, y1)`` (edges included).

    >>> in_mask(np.array([[5.0, 5.0], [20.0, 5.0]]), ((0, 0, 10, 10),)).tolist()
    [True, False]
    """
    inside = np.zeros(len(pts), bool)
    for x0, y0, x1, y1 in rects:
        inside |= (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
    return inside


def _track(
    img_a: np.ndarray, img_b: np.ndarray, params: TrackParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`track_pair` at the images' own resolution."""
    H, W = img_a.shape
    c = corners(img_a, params)
    empty = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    if len(c) == 0:
        return empty
    p0 = c.astype(np.float32).reshape(-1, 1, 2)
    lk = dict(
        winSize=(params.window_px, params.window_px),
        maxLevel=params.levels,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 0.001),
    )
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img_a, img_b, p0, None, **lk)  # type: ignore[call-overload]  # cv2 stubs: nextPts may be None (OpenCV allocates it)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(img_b, img_a, p1, None, **lk)  # type: ignore[call-overload]  # cv2 stubs: nextPts may be None (OpenCV allocates it)
    a, b = p0.reshape(-1, 2).astype(float), p1.reshape(-1, 2).astype(float)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - a, axis=1)
    m = params.border_px
    inside = (b[:, 0] >= m) & (b[:, 0] <= W - 1 - m) & (b[:, 1] >= m) & (b[:, 1] <= H - 1 - m)
    ok = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb < params.fb_max_px) & inside
    ok &= np.all(np.isfinite(b), axis=1)
    return a[ok], b[ok], fb[ok]


def corners(img: np.ndarray, params: TrackParams = TrackParams()) -> np.ndarray:
    """Shi–Tomasi corners ``(M, 2)`` of an 8-bit gray frame, strongest first, in its pixels,
    found on the frame area-averaged by ``params.corner_downscale`` (see there)."""
    k = params.corner_downscale
    small = img
    if k > 1 and min(img.shape) >= 8 * k:
        size = (img.shape[1] // k, img.shape[0] // k)
        small = cv2.resize(img[: size[1] * k, : size[0] * k], size, interpolation=cv2.INTER_AREA)
    else:
        k = 1
    block = max(3, 2 * math.ceil((params.block_size / k - 1) / 2) + 1)
    c = cv2.goodFeaturesToTrack(
        small,
        maxCorners=params.max_corners,
        qualityLevel=params.quality,
        minDistance=max(1.0, params.min_distance_px / k),
        blockSize=block,
    )
    if c is None or len(c) == 0:
        return np.zeros((0, 2))
    if k == 1:
        return c.reshape(-1, 2).astype(float)
    # pixel centres: (x_full + 0.5) = k (x_small + 0.5)
    return (c.reshape(-1, 2).astype(float) + 0.5) * k - 0.5


def track_frames(
    read_frame: Callable[[int], np.ndarray],
    n_frames: int,
    params: TrackParams = TrackParams(),
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
) -> FeatureTracks:
    """Tracks of every consecutive pair of ``n_frames`` frames read by ``read_frame(i)``.

    Pairs are tracked on ``workers`` threads (default: every usable core; the tracks do not
    depend on it, :mod:`blurtrack.features.pairs`). Raises :class:`FeatureTrackError` for
    fewer than two frames.
    """
    from blurtrack.features.pairs import map_pairs

    if n_frames < 2:
        raise FeatureTrackError(f"feature tracks need at least 2 frames, got {n_frames}")
    pairs = map_pairs(
        lambda f, a, b: track_pair(a, b, params),
        lambda i: to_gray8(read_frame(i)),
        range(n_frames - 1),
        workers,
        progress,
    )
    return tracks_of_pairs(pairs, n_frames)


def tracks_of_pairs(
    pairs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], n_frames: int
) -> FeatureTracks:
    """:class:`FeatureTracks` of :func:`track_pair`'s results for the pairs ``(i, i + 1)``,
    ``i = 0 … n_frames − 2`` in order."""
    if len(pairs) != n_frames - 1:
        raise FeatureTrackError(f"{len(pairs)} frame pairs tracked for {n_frames} frames")
    frame_a = np.concatenate([np.full(len(a), i) for i, (a, _, _) in enumerate(pairs)])
    return FeatureTracks(
        frame_a,
        frame_a + 1,
        np.concatenate([a for a, _, _ in pairs]),
        np.concatenate([b for _, b, _ in pairs]),
        np.concatenate([e for _, _, e in pairs]),
        int(n_frames),
        np.array([len(a) for a, _, _ in pairs], dtype=np.int64),
    )
