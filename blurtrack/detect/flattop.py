"""The flat top of a streak's cross-section: how much wider than its own edges its lit band is.

A point light's cross-section is the point spread itself. For a Gaussian of any sigma the
width at 90 % of the peak is :data:`POINT_RATIO` (``sqrt(ln(10/9) / ln 2)`` = 0.39) of the
width at half the peak. An extended source (a letter's stroke, a lit bar, a window's edge)
lights a band with a flat top, blurred at its edges by the same point spread: a box of
half-width ``b`` convolved with the Gaussian, whose ratio grows with ``b / sigma`` (0.58 at
``b = 3 sigma``, 0.79 at ``6 sigma``). Inverting that curve gives the cross-section's rms width
over the sigma of its own edges, ``sqrt(1 + b^2 / (3 sigma^2))``: a width ratio against the
streak's *own* point spread (:func:`own_width_ratio`). It needs no estimate of the frame's
point spread, which is the median of the frame's widths and so, in a frame whose every line
is a letter's stroke, the stroke's width: against it every stroke measures one PSF wide.

A defocused dot (a disc) is rounder than a box: a disc of radius 5 sigmas measures 1.7 (between
``source.point_width_ratio`` and ``extended_width_ratio``: never ``extended`` from this alone).
Two dots side by side two sigmas apart measure 2 (they are not one point light).

The mean cross-section of each streak is taken over up to :data:`SECTIONS` centre-line points
in the middle half of its line (the ends are the end caps; a line too short for that: sections
through its middle point in as many directions), on the smoothed image, across
``HALF_PSF`` frame PSF sigmas either side; sections whose core holds light of a saturated pixel
(:func:`near_saturation`) are left out (a clipped top is flat whatever drew it). Where fewer than
:data:`MIN_SECTIONS` remain: NaN (no evidence either way). A band whose half level lies
beyond the window is wider than the window: as flat as the curve goes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.lines.normal import normal_cdf
from blurtrack.detect.lines.sampling import sample_image

#: Width at 90 % of the peak over the width at half the peak, for a Gaussian cross-section.
POINT_RATIO = float(np.sqrt(np.log(10.0 / 9.0) / np.log(2.0)))
#: Centre-line points whose cross-sections are sampled per streak (a short line: directions
#: through its middle point).
SECTIONS = 8
#: Fewest unsaturated cross-sections that give a mean.
MIN_SECTIONS = 5
#: The sampled window reaches this many frame PSF sigmas either side of the centre line (a
#: band up to ~12 sigmas wide has its half level inside).
HALF_PSF = 6.0
#: ``(SECTIONS, 2)`` unit directions of the sections through a short line's middle point (fewer
#: than ``2 MIN_SECTIONS`` centre-line points, ~1 px apart): a point light's spot is round.
_DIRECTIONS = np.stack(
    [
        np.cos(np.arange(SECTIONS) * np.pi / SECTIONS),
        np.sin(np.arange(SECTIONS) * np.pi / SECTIONS),
    ],
    axis=1,
)
#: Streaks nearest the frame's point spread whose flat tops check it
#: (:func:`frame_own_width_ratio`).
PSF_CHECK = 16
#: The cross-section's peak is sought this near the centre line (px).
PEAK_REACH_PX = 1.0
#: A mean cross-section whose peak (over its minimum) is under this many noise sigmas of the
#: smoothed image holds no light to measure (the background's own fluctuations are as "flat").
NOISE_SIGMAS = 3.0
#: Sample spacing across the line (px).
STEP_PX = 0.5
#: Sections with a saturated pixel of the unsmoothed signal within the smoothing's reach of
#: their samples within this many PSF sigmas of the centre are clipped.
CORE_PSF = 2.0
#: The smoothing's reach, in its sigmas (a Gaussian's weight beyond 2.5 sigmas is 1 %).
CLIP_REACH_SIGMAS = 2.5


def _run(v: np.ndarray, centre: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(N,)`` indices of the samples just outside the run of samples ``>= level`` around
    ``centre`` in each row of ``v (N, K)``: left (-1 where the run reaches the row's start)
    and right (``K`` where it reaches its end)."""
    K = v.shape[1]
    k = np.arange(K)[None, :]
    below = v < level[:, None]
    c = centre[:, None]
    left = np.where(below & (k < c), k, -1).max(axis=1)
    right = np.where(below & (k > c), k, K).min(axis=1)
    return left, right


def _crossings(v: np.ndarray, centre: np.ndarray, level: np.ndarray) -> np.ndarray:
    """``(N,)`` width (in samples) of the run of samples ``>= level`` around ``centre`` in each
    row of ``v (N, K)``, the crossings interpolated linearly; infinite where the run reaches an
    end of the row."""
    N, K = v.shape
    left, right = _run(v, centre, level)
    ok = (left >= 0) & (right < K)
    out = np.full(N, np.inf)
    if not ok.any():
        return out
    r = np.flatnonzero(ok)
    lo, hi = left[r], right[r]
    t = level[r]
    v_lo, v_lo1 = v[r, lo], v[r, lo + 1]
    v_hi1, v_hi = v[r, hi - 1], v[r, hi]
    with np.errstate(divide="ignore", invalid="ignore"):
        xl = lo + np.where(v_lo1 > v_lo, (t - v_lo) / (v_lo1 - v_lo), 1.0)
        xr = hi - np.where(v_hi1 > v_hi, (t - v_hi) / (v_hi1 - v_hi), 1.0)
    out[r] = xr - xl
    return out


@cache
def _ratio_curve() -> tuple[np.ndarray, np.ndarray]:
    """The box-convolved-with-Gaussian curve: ``(ratio, width_ratio)``, ``ratio`` (W90 / W50)
    increasing from :data:`POINT_RATIO` at ``b = 0``, ``width_ratio = sqrt(1 + b^2 / 3)`` (b in
    sigmas)."""
    b = np.linspace(0.0, 20.0, 201)
    x = np.arange(-30.0, 30.0 + 1e-9, 0.02)
    v = normal_cdf(x[None, :] + b[:, None]) - normal_cdf(x[None, :] - b[:, None])
    v[0] = np.exp(-0.5 * x * x)
    centre = np.full(b.size, x.size // 2)
    peak = v[:, x.size // 2]
    ratio = _crossings(v, centre, 0.9 * peak) / _crossings(v, centre, 0.5 * peak)
    ratio[0] = POINT_RATIO  # b = 0, exactly (the grid's crossings are within 1e-5)
    # Nearly flat (0.39) while b < sigma: the curve's strictly increasing part (its first b
    # at each ratio), so that the inverse is a function.
    ratio = np.maximum.accumulate(ratio)
    keep = np.r_[True, np.diff(ratio) > 0]
    return ratio[keep], np.sqrt(1.0 + b[keep] ** 2 / 3.0)


def width_ratio_of(ratio: np.ndarray) -> np.ndarray:
    """The rms width over the edges' sigma (``sqrt(1 + b^2 / (3 sigma^2))``) of the box-blurred
    cross-section whose W90 / W50 is ``ratio`` (any shape; 1 at or below
    :data:`POINT_RATIO`, NaN stays NaN)."""
    r, w = _ratio_curve()
    out = np.interp(np.nan_to_num(ratio, nan=0.0), r, w)
    return np.where(np.isfinite(ratio), out, np.nan)


def mean_sections(
    smooth: np.ndarray,
    near_clip: np.ndarray | None,
    points: list[np.ndarray],
    psf: float,
) -> np.ndarray:
    """``(N, K)`` each streak's mean cross-section on ``smooth`` (background: its minimum,
    subtracted), ``K = 2 ceil(HALF_PSF psf / STEP_PX) + 1`` samples :data:`STEP_PX` apart
    centred on the line; NaN rows where too few unsaturated sections (module docstring).
    ``near_clip``: :func:`near_saturation` of the frame (None: nothing saturated). All
    streaks at once: one sampling call per image."""
    n = len(points)
    half = int(np.ceil(HALF_PSF * psf / STEP_PX))
    off = np.arange(-half, half + 1) * STEP_PX
    out = np.full((n, off.size), np.nan)
    sizes = np.fromiter((len(p) for p in points), np.int64, n)
    use = np.flatnonzero(sizes > 0)
    if use.size == 0:
        return out
    sizes = sizes[use]
    flat = np.concatenate([np.asarray(points[i], float).reshape(-1, 2) for i in use])
    starts = (np.cumsum(sizes) - sizes)[:, None]
    last = sizes[:, None] - 1
    # (U, S) centre-line points: spread over the middle half; a short line's middle point.
    long_ = sizes >= 2 * MIN_SECTIONS
    frac = np.linspace(0.0, 1.0, SECTIONS)[None, :]
    lo, hi = sizes // 4, (3 * sizes) // 4 - 1
    local = np.rint(lo[:, None] + frac * (hi - lo)[:, None]).astype(np.int64)
    local = np.where(long_[:, None], local, (sizes // 2)[:, None])
    centre = flat[starts + local]
    tan = flat[starts + np.minimum(local + 1, last)] - flat[starts + np.maximum(local - 1, 0)]
    tan /= np.maximum(np.linalg.norm(tan, axis=2, keepdims=True), 1e-9)
    nrm = np.stack([-tan[..., 1], tan[..., 0]], axis=2)
    nrm = np.where(long_[:, None, None], nrm, _DIRECTIONS[None])
    off32, centre, nrm = off.astype(np.float32), centre.astype(np.float32), nrm.astype(np.float32)
    x = centre[..., 0, None] + off32 * nrm[..., 0, None]
    y = centre[..., 1, None] + off32 * nrm[..., 1, None]
    v = sample_image(smooth, x, y)  # (U, S, K)
    clipped: np.ndarray = np.zeros(x.shape[:2], bool)
    if near_clip is not None:
        core = np.abs(off) <= CORE_PSF * psf
        clipped = np.any(sample_image(near_clip, x[..., core], y[..., core]) > 0, axis=2)
    # The mean over each line's unclipped sections (a crossing line in one of them adds a
    # fraction of its light, well under the 50 % level, across the section).
    keep = ~clipped
    count = keep.sum(axis=1)
    mean = np.einsum("usk,us->uk", v, keep.astype(v.dtype)) / np.maximum(count, 1)[:, None]
    mean -= mean.min(axis=1, keepdims=True)
    ok = count >= MIN_SECTIONS
    out[use[ok]] = mean[ok]
    return out


def near_saturation(
    signal: np.ndarray, saturation: float, smooth_sigma_px: float
) -> np.ndarray | None:
    """``(H, W)`` float32, 1 within the smoothing's reach (``CLIP_REACH_SIGMAS`` smoothing
    sigmas, plus a pixel) of a pixel of the unsmoothed ``signal`` at ``saturation``, else 0:
    the smoothed image there holds clipped light. None where no pixel is saturated."""
    sat = signal >= saturation
    if not sat.any():
        return None
    r = int(np.ceil(CLIP_REACH_SIGMAS * smooth_sigma_px)) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(sat.astype(np.uint8), kernel).astype(np.float32)


def own_width_ratio(
    smooth: np.ndarray,
    near_clip: np.ndarray | None,
    points: list[np.ndarray],
    psf: float,
    noise: float = 0.0,
) -> np.ndarray:
    """``(N,)`` each streak's cross-section rms width over the sigma of its own edges, from the
    flat top of its mean cross-section (module docstring); NaN where not measured.
    ``psf``: the frame's cross-section sigma in ``smooth`` (sets the window only); ``noise``:
    its noise sigma (a section's peak under :data:`NOISE_SIGMAS` of it is no light to measure:
    NaN)."""
    prof = mean_sections(smooth, near_clip, points, psf)
    return own_ratio_of_profiles(prof, NOISE_SIGMAS * noise)


@dataclass(frozen=True)
class OwnWidths:
    """A frame's streaks against their own edges (:func:`frame_own_width_ratio`): ``ratio``
    ``(N,)`` (NaN: not measured) and whether the frame's point spread is an extended source's
    (``psf_extended``: its reference streaks measure, at the median, wider than
    ``source.extended_width_ratio`` against their own edges, so no width against it tells a
    point light)."""

    ratio: np.ndarray
    psf_extended: bool


def frame_own_width_ratio(
    ctx: FrameContext, points: list[np.ndarray], width_px: np.ndarray, psf: float
) -> OwnWidths:
    """:func:`own_width_ratio` of a frame's streaks (``points``, ``width_px`` as measured on
    the frame ``ctx``) where its point spread ``psf`` (the median of ``width_px``; for the
    gyro pass's streaks, the session's) is not a point light's; all NaN where it is.

    Against a point light's ``psf`` the widths tell what the streaks' own edges would: a band
    measuring more than a limit against its own edges measures more than that against the
    spread of its edges, which is the optics'. So the own edges are needed only where ``psf``
    is not a point light's: the :data:`PSF_CHECK` streaks whose widths lie nearest ``psf``
    (its reference) are measured first, and where the median of their own ratios is within
    ``source.point_width_ratio`` the frame's ``psf`` is a point light's (a laser-dot frame:
    one sampling of a few lines); above ``source.extended_width_ratio`` an extended
    source's."""
    sp = ctx.params.source
    smooth = ctx.smooth
    n = len(points)
    w = np.asarray(width_px, float)
    near_clip = None
    if ctx.sat_comp is not None:  # some pixel of the frame is saturated
        near_clip = near_saturation(ctx.signal, ctx.saturation, ctx.smooth_sigma_px)
    d = np.where(np.isfinite(w), np.abs(w - psf), np.inf)
    ref = np.argsort(d, kind="stable")[:PSF_CHECK]
    noise = ctx.noise_smooth
    own_ref = own_width_ratio(smooth, near_clip, [points[i] for i in ref], psf, noise)
    med = float(np.nanmedian(own_ref)) if np.isfinite(own_ref).any() else float("nan")
    if not med > sp.point_width_ratio:
        return OwnWidths(np.full(n, np.nan), False)
    own = np.full(n, np.nan)
    own[ref] = own_ref
    rest = np.setdiff1d(np.arange(n), ref)  # the reference is measured already
    if rest.size:
        own[rest] = own_width_ratio(smooth, near_clip, [points[i] for i in rest], psf, noise)
    return OwnWidths(own, bool(med > sp.extended_width_ratio))


def own_ratio_of_profiles(prof: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """``(N,)`` the width ratio against its own edges of each cross-section ``prof (N, K)``,
    centred and sampled :data:`STEP_PX` apart (NaN rows, and rows whose peak is not above
    ``floor``: NaN)."""
    n = len(prof)
    out = np.full(n, np.nan)
    has = np.isfinite(prof[:, 0]) if n else np.zeros(0, bool)
    if not has.any():
        return out
    v = prof[has]
    K = v.shape[1]
    # The peak of the light the line lies on: the centre line is the cross-section's
    # centroid, on a point light's peak or a band's plateau (within PEAK_REACH_PX), or between
    # two arms of a hairpin side by side; the peak is the highest sample of the run above half
    # the centre's value (one arm's top, where a point light's arms are resolved: a
    # neighbouring band lies beyond a dip below half).
    reach = int(np.ceil(PEAK_REACH_PX / STEP_PX))
    mid = K // 2
    rows = np.arange(len(v))
    at = mid - reach + np.argmax(v[:, mid - reach : mid + reach + 1], axis=1)
    left, right = _run(v, at, 0.5 * v[rows, at])
    k = np.arange(K)[None, :]
    inside = (k > left[:, None]) & (k < right[:, None])
    centre = np.argmax(np.where(inside, v, -np.inf), axis=1)
    peak = v[rows, centre]
    good = peak > max(floor, 0.0)
    w90 = _crossings(v, centre, 0.9 * peak)
    w50 = _crossings(v, centre, 0.5 * peak)
    # A band still above half its peak at the window's edge is wider than the window (more
    # than HALF_PSF frame sigmas to a side): as flat as the curve goes.
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isinf(w50), 1.0, w90 / w50)
    ratio = np.where(good & (w50 > 0), ratio, np.nan)
    out[has] = width_ratio_of(ratio)
    return out
