"""Measured evidence that a detection is one whole point-light streak with trustworthy ends.

Everything is measured against the frame's own point spread: ``psf``, the frame's
cross-section sigma in the smoothed image (:attr:`blurtrack.detect.frame.FrameStreaks.sigma_c_px`,
the median of the streaks' measured widths), so no threshold is a pixel count fitted to one
file.

- ``width_ratio``: the streak's measured cross-section sigma (saturated streaks: from the
  flanks of the clipped cross-sections) over ``psf``. A point light's cross-section is the PSF
  all along (ratio 1).
- ``own_width_ratio``: the same ratio against the streak's own edges, from the flat top of
  its mean unsaturated cross-section (:mod:`blurtrack.detect.flattop`): a frame of letters'
  strokes has the strokes' width as ``psf``, but a stroke's top is flat where a point light's
  is the PSF's peak. Wider than ``extended_width_ratio`` against its own edges the source is
  extended, whatever ``width_ratio`` says.
- ``fill``: the lit area (pixels above the segmentation threshold) of the streak's connected
  component over the area its streaks would light if each were a point light: at every
  centre-line point a Gaussian cross-section of sigma ``psf`` carrying the measured
  cross-section integral lights ``2 h`` pixels, ``h = psf sqrt(2 ln(a / threshold))`` with
  ``a`` its peak (saturated profiles are unclipped before, so a blown-out light's wider lit
  region is expected), plus a disc of radius ``h`` at each end. A lit window, a screen, a
  sign's strokes or ground glare light far more than that.
- ``end_light``: ``(N, 2)`` light just beyond each end (the cross-section integral, maximum over
  the steps from ``END_GAP_SIGMAS`` sigmas out to ``END_REACH_SIGMAS`` sigmas plus
  ``END_REACH_PX``) over the streak's brightness there: a dot's erf edge leaves
  ``Phi(-END_GAP_SIGMAS)`` of it, a neighbour's light touching or continuing the end much
  more, and the edge fit of that end (which finds no dip to stop at there) is then not this
  dot's end.
  NaN where that window leaves the frame: the end is too near the border to be measured
  (``reason`` ``clipped``, whatever ``border_margin_px`` says).
- ``contrast``: the streak's brightest centre-line point in the smoothed image over the
  segmentation threshold. Near the threshold the lit region is only the core of whatever
  source drew the line, and the fill cannot tell a point from a broad light: a source ``r``
  (``extended_width_ratio``) times the PSF wide with peak ``a`` lights a band of half-width
  ``r psf sqrt(2 L)``, ``L = ln(a / threshold)``, where a point light with its profile would
  light ``psf sqrt(2 (L + ln r))``; their ratio exceeds ``point_fill`` ``f`` only where
  ``L > f^2 ln r / (r^2 - f^2)`` (:func:`min_contrast`: 2.44 with the defaults). A fainter
  streak is never ``point``.
- ``component``: index of the streak's connected component (-1 none), ``shared`` how many of
  the frame's streaks lie on it.

:func:`classify_source` turns these into ``point``, ``extended`` or ``undetermined``
(thresholds in :class:`blurtrack.detect.params.SourceParams`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from blurtrack.detect.context import FrameContext
from blurtrack.detect.flattop import frame_own_width_ratio
from blurtrack.detect.lines.sampling import sample_image
from blurtrack.detect.lines.segment import Components
from blurtrack.detect.params import SourceParams
from blurtrack.errors import DetectionError

#: The closed set of ``source`` values.
SOURCES = ("point", "extended", "undetermined")

#: The end-light window starts this many sigmas beyond the end (half-level point), where a
#: dot's own erf edge has fallen to Phi(-3) = 0.13 % of its plateau.
END_GAP_SIGMAS = 3.0
#: ... and reaches this many sigmas plus END_REACH_PX further. The edge fit's area starts at
#: the profile's minimum beyond the end (:mod:`blurtrack.detect.lines.endpoints`), so a
#: neighbour's light peaking ``D`` beyond the end is read only through its tail inside the dip
#: at about ``D / 2``: ``sigma G(-D / (2 sigma))`` of area per unit of its brightness, 0.01
#: sigma at ``D = 4 sigma`` (``G(z) = z Phi(z) + phi(z)``). Light from 4 sigmas on no longer
#: moves the end; light between 3 and 4 sigmas leaves no dip to stop at.
END_REACH_SIGMAS = 1.0
END_REACH_PX = 0.0
#: Half-width of the end-light cross-section integral, in sigmas: +-2 sigma holds 95 % of a
#: Gaussian cross-section.
END_HALF_SIGMAS = 2.0
#: Centre-line points on each side of an end that give its outward direction (~1 px apart).
TANGENT_POINTS = 3


@dataclass
class Evidence:
    """Per-streak measurements (one row per streak, see the module docstring)."""

    width_ratio: np.ndarray
    own_width_ratio: np.ndarray
    fill: np.ndarray
    end_light: np.ndarray
    component: np.ndarray
    shared: np.ndarray
    source: np.ndarray  # object array of SOURCES
    contrast: np.ndarray

    def __len__(self) -> int:
        return int(self.width_ratio.size)

    @staticmethod
    def empty() -> Evidence:
        z = np.zeros(0)
        return Evidence(
            z,
            z.copy(),
            z.copy(),
            np.zeros((0, 2)),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0, object),
            z.copy(),
        )

    @staticmethod
    def concat(parts: list[Evidence]) -> Evidence:
        """The rows of ``parts`` one after the other."""
        if not parts:
            return Evidence.empty()
        return Evidence(
            *(np.concatenate([getattr(e, f.name) for e in parts]) for f in fields(Evidence))
        )

    def take(self, rows: np.ndarray) -> Evidence:
        return Evidence(
            self.width_ratio[rows],
            self.own_width_ratio[rows],
            self.fill[rows],
            self.end_light[rows],
            self.component[rows],
            self.shared[rows],
            self.source[rows],
            self.contrast[rows],
        )


def _component_of(points: list[np.ndarray], comps: Components) -> np.ndarray:
    """``(N,)`` index into ``comps`` of the component under each streak's middle point (-1:
    none, e.g. an artefact the filter dropped or a point off the lit pixels)."""
    n = len(points)
    out = np.full(n, -1, np.int64)
    if n == 0 or comps.ids.size == 0:
        return out
    H, W = comps.labels.shape
    mids = np.array([p[len(p) // 2] for p in points], float).reshape(-1, 2)
    x = np.clip(np.rint(mids[:, 0]).astype(np.int64), 0, W - 1)
    y = np.clip(np.rint(mids[:, 1]).astype(np.int64), 0, H - 1)
    lab = comps.labels[y, x].astype(np.int64)
    lut = np.full(int(comps.labels.max()) + 1, -1, np.int64)
    lut[comps.ids.astype(np.int64)] = np.arange(comps.ids.size)
    return lut[lab]


def _expected_area(profile: list[np.ndarray], psf: float, threshold: float) -> np.ndarray:
    """``(N,)`` pixels a point light with these profiles would light above ``threshold``."""
    if not profile:
        return np.zeros(0)
    norm = np.sqrt(2.0 * np.pi) * psf  # cross-section integral of a unit-peak Gaussian
    # Elementwise over all profiles at once; each profile's sum over its own slice (the very
    # pairwise sum of its own array).
    sizes = np.array([np.size(pr) for pr in profile], np.int64)
    a = np.concatenate([np.asarray(pr, float).ravel() for pr in profile]) / norm
    h = psf * np.sqrt(2.0 * np.log(np.maximum(a / threshold, 1.0)))
    stops = np.cumsum(sizes)
    starts = stops - sizes
    some = sizes > 0
    caps = np.zeros(len(profile))
    caps[some] = np.pi * (h[starts[some]] ** 2 + h[stops[some] - 1] ** 2) / 2.0
    sums = np.array([h[i:j].sum() for i, j in zip(starts.tolist(), stops.tolist(), strict=True)])
    return np.asarray(2.0 * sums + caps)


def _end_frames(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 2, 2)`` ends and ``(N, 2, 2)`` outward unit tangents (end A, end B); every line
    has at least one point."""
    n = len(points)
    ends = np.zeros((n, 2, 2))
    tang = np.zeros((n, 2, 2))
    if n == 0:
        return ends, tang
    # One flat gather: each line's first and last points, and those TANGENT_POINTS inside.
    sizes = np.array([len(p) for p in points], np.int64)
    if np.any(sizes == 0):
        raise DetectionError("a streak's centre line has no points")
    flat = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in points])
    last = np.cumsum(sizes) - 1
    first = last - sizes + 1
    k = np.minimum(TANGENT_POINTS, sizes - 1)
    ends[:, 0], ends[:, 1] = flat[first], flat[last]
    has = k >= 1
    tang[has, 0] = flat[first[has]] - flat[first[has] + k[has]]
    tang[has, 1] = flat[last[has]] - flat[last[has] - k[has]]
    nrm = np.linalg.norm(tang, axis=2, keepdims=True)
    tang = np.where(nrm > 1e-9, tang / np.maximum(nrm, 1e-9), [1.0, 0.0])
    return ends, tang


def _peaks(profile: list[np.ndarray]) -> np.ndarray:
    """``(N,)`` each profile's highest value (0 for an empty one), in one flat pass."""
    sizes = np.fromiter(map(np.size, profile), np.int64, len(profile))
    peak = np.zeros(len(profile))
    has = sizes > 0
    if has.any():
        flat = np.concatenate([np.asarray(p, float).ravel() for p in profile])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        peak[has] = np.maximum.reduceat(flat, starts[has])
    return peak


def _end_light(
    smooth: np.ndarray,
    points: list[np.ndarray],
    plateau: np.ndarray,
    profile: list[np.ndarray],
    psf: float,
) -> np.ndarray:
    """``(N, 2)`` light beyond each end over the streak's brightness at that end."""
    n = len(points)
    if n == 0:
        return np.zeros((0, 2))
    ends, tang = _end_frames(points)
    d = np.arange(END_GAP_SIGMAS * psf, (END_GAP_SIGMAS + END_REACH_SIGMAS) * psf + END_REACH_PX)
    half = int(np.ceil(END_HALF_SIGMAS * psf))
    k = np.arange(-half, half + 1, dtype=float)
    nrm = np.stack([-tang[..., 1], tang[..., 0]], axis=-1)
    # (N, 2, D, K) sample positions
    pos = (
        ends[:, :, None, None, :]
        + d[None, None, :, None, None] * tang[:, :, None, None, :]
        + k[None, None, None, :, None] * nrm[:, :, None, None, :]
    )
    vals = sample_image(smooth, pos[..., 0], pos[..., 1])
    light = vals.sum(axis=3).max(axis=2)  # (N, 2) cross-section integral (1 px steps)
    # An end whose window leaves the frame cannot show its edge: unknown (NaN), ``clipped``.
    H, W = smooth.shape
    x, y = pos[..., 0], pos[..., 1]
    out = ((x < 0) | (x > W - 1) | (y < 0) | (y > H - 1)).any(axis=(2, 3))
    light = np.where(out, np.nan, light)
    peak = _peaks(profile)
    ref = np.where(np.isfinite(plateau) & (plateau > 0), plateau, peak[:, None])
    return np.asarray(light / np.maximum(ref, 1e-12))


def min_contrast(p: SourceParams) -> float:
    """Least peak over the segmentation threshold at which the fill tells a point light from a
    source ``extended_width_ratio`` times the PSF wide (module docstring, ``contrast``):
    ``exp(f^2 ln r / (r^2 - f^2))``, ``r`` that ratio, ``f`` ``point_fill``; infinite where
    ``f >= r`` (no contrast makes such a source fill more than ``f``)."""
    r, f = p.extended_width_ratio, p.point_fill
    if f >= r:
        return float("inf")
    return float(np.exp(f * f * np.log(r) / (r * r - f * f)))


def _contrast(smooth: np.ndarray, points: list[np.ndarray], threshold: float) -> np.ndarray:
    """``(N,)`` each streak's brightest centre-line point in ``smooth`` over ``threshold``."""
    if not points:
        return np.zeros(0)
    sizes = np.fromiter(map(len, points), np.int64, len(points))
    flat = np.concatenate(points).reshape(-1, 2)
    vals = sample_image(smooth, flat[:, 0], flat[:, 1])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    peak = np.full(len(points), -np.inf)
    has = sizes > 0
    peak[has] = np.maximum.reduceat(vals, starts[has])
    return np.asarray(peak / max(threshold, 1e-12))


def classify_source(
    width_ratio: np.ndarray,
    fill: np.ndarray,
    p: SourceParams,
    contrast: np.ndarray | None = None,
    own_width_ratio: np.ndarray | None = None,
    psf_extended: bool = False,
    unmeasured: np.ndarray | None = None,
) -> np.ndarray:
    """``(N,)`` object array of ``point``, ``extended`` or ``undetermined``: extended where the
    streak is far wider than the PSF or its lit region far larger than a point light's;
    point where both are within a point light's spread and (given ``contrast``) the streak
    is bright enough for the fill to tell (:func:`min_contrast`); undetermined otherwise (and
    where a measurement is missing). ``own_width_ratio`` (where measured): the width against
    the streak's own edges; above ``extended_width_ratio`` the source is extended too.
    ``psf_extended``: the frame's PSF is an extended source's
    (:class:`~blurtrack.detect.flattop.OwnWidths`); a point light must then also measure
    within ``point_width_ratio`` against its own edges. ``unmeasured``: ``(N,)`` the streaks
    whose width no cross-section can give (two blown-out arms of one hairpin, whose clipped
    cores run into each other): the width against ``psf`` does not count against ``point``
    for them; the fill, the contrast and the own edges decide as for every streak."""
    wr = np.where(np.isfinite(width_ratio), width_ratio, np.inf)
    if unmeasured is not None:
        wr = np.where(np.asarray(unmeasured, bool), 0.0, wr)
    fl = np.where(np.isfinite(fill), fill, np.inf)
    out = np.full(wr.size, "undetermined", object)
    point = (wr <= p.point_width_ratio) & (fl <= p.point_fill)
    wide = np.isfinite(width_ratio) & (width_ratio > p.extended_width_ratio)
    if own_width_ratio is not None:
        # The same two limits against the streak's own edges: wider than
        # ``extended_width_ratio`` is extended (no dot, nor two dots half a PSF apart, is);
        # where the frame's PSF is itself an extended source's, a point light must also
        # measure within ``point_width_ratio`` against its own edges.
        own = np.nan_to_num(own_width_ratio, nan=np.inf if psf_extended else 0.0)
        wide |= np.isfinite(own) & (own > p.extended_width_ratio)
        if psf_extended:
            point &= own <= p.point_width_ratio
    if contrast is not None:
        point &= np.nan_to_num(contrast, nan=0.0) >= min_contrast(p)
    out[point] = "point"
    ext = wide | (np.isfinite(fill) & (fill > p.extended_fill))
    out[ext] = "extended"
    return out


def assess(
    ctx: FrameContext,
    points: list[np.ndarray],
    profile: list[np.ndarray],
    plateau: np.ndarray,
    width_px: np.ndarray,
    psf: float,
    unmeasured: np.ndarray | None = None,
) -> Evidence:
    """The :class:`Evidence` of a frame's streaks (``points``, ``profile``, ``plateau``,
    ``width_px`` as in :class:`~blurtrack.detect.frame.FrameStreaks`) on the frame ``ctx``
    (its smoothed image, components, threshold and ``params.source``) with cross-section
    sigma ``psf``; ``unmeasured``: as in :func:`classify_source`."""
    smooth, comps, threshold, p = ctx.smooth, ctx.comps, ctx.threshold, ctx.params.source
    n = len(points)
    if n == 0:
        return Evidence.empty()
    comp = _component_of(points, comps)
    has = comp >= 0
    C = comps.ids.size
    shared = np.zeros(n, np.int64)
    fill = np.full(n, np.nan)
    if has.any():
        counts = np.bincount(comp[has], minlength=C)
        shared[has] = counts[comp[has]]
        expected = np.bincount(
            comp[has],
            _expected_area([profile[i] for i in np.flatnonzero(has)], psf, threshold),
            minlength=C,
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = comps.areas / expected
        fill[has] = ratio[comp[has]]
    width_ratio = np.asarray(width_px, float) / psf
    own = frame_own_width_ratio(ctx, points, width_px, psf)
    light = _end_light(smooth, points, np.asarray(plateau, float), profile, psf)
    contrast = _contrast(smooth, points, threshold)
    source = classify_source(
        width_ratio, fill, p, contrast, own.ratio, own.psf_extended, unmeasured
    )
    return Evidence(width_ratio, own.ratio, fill, light, comp, shared, source, contrast)
