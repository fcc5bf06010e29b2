"""Detection in one frame: from a stored image to measured, not yet oriented, streaks."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from blurtrack.allocator import keep_heap
from blurtrack.detect.context import FrameContext, prepare_and_segment
from blurtrack.detect.image import PreparedFrame
from blurtrack.detect.lines.measure import LineSet, Measured, measure_lines
from blurtrack.detect.lines.measure import combine as _combine
from blurtrack.detect.lines.ragged import Ragged, split_at
from blurtrack.detect.lines.segment import Components, axis_polylines
from blurtrack.detect.lines.skeleton import trace_paths
from blurtrack.detect.params import DetectParams
from blurtrack.detect.separation.anchored import anchored
from blurtrack.detect.separation.separate import separate
from blurtrack.detect.trust import Evidence, assess

#: Flag columns, in table order.
FLAG_NAMES: tuple[str, ...] = ("clipped", "saturated", "crossing", "merged", "looped", "faint")


@dataclass
class FrameStreaks:
    """Streaks of one frame, each oriented from its end A to its end B (arbitrary so far).

    Arrays have one row per streak (N). ``points``/``profile`` are per-streak lists of
    ``(n, 2)`` / ``(n,)`` arrays. ``flags`` maps each name of :data:`FLAG_NAMES` to ``(N,)``
    bools. ``snr``: peak of the smoothed signal in noise sigmas. ``sigma_c_px``: the frame's
    cross-section sigma in the smoothed image. ``shape``: ``(H, W)``. ``saturated_fraction``:
    the fraction of the frame's pixels at the saturation level (an over-exposed frame).
    """

    shape: tuple[int, int]
    end_a: np.ndarray
    end_b: np.ndarray
    time_mid: np.ndarray
    plateau: np.ndarray
    length_px: np.ndarray
    width_px: np.ndarray
    snr: np.ndarray
    points: list[np.ndarray]
    profile: list[np.ndarray]
    flags: dict[str, np.ndarray]
    sigma_c_px: float
    noise: float
    hot_pixels: int
    short: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    saturated_fraction: float = 0.0
    #: The streaks' ``(shape_deviation_px, thick_saturated, quality_ok)``
    #: (:func:`blurtrack.detect.separation.quality.frame_quality`; independent of which end is A),
    #: where the frame's worker computed them; None: the table computes them.
    quality: tuple[np.ndarray, ...] | None = None
    #: Point light or extended source, light beyond the ends (:mod:`blurtrack.detect.trust`),
    #: measured on the frame's image; None: not measured (every streak ``undetermined``).
    evidence: Evidence | None = None
    #: ``(N,)`` the streaks the gyro-template pass measured along its predicted curve (a
    #: hairpin as its two arms); empty: none (:mod:`blurtrack.detect.gyro.gyrotrust`).
    along_curve: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    #: ``(N,)`` the streaks not ``quality_ok`` against which the image has one doubt the gyro
    #: may lift (:func:`blurtrack.detect.separation.quality.one_doubt`), set with ``quality``; the
    #: gyro's check confirms them where it measures their start-to-end vector right.
    one_doubt: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    #: The colour (B, G, R, relative to its strongest channel) of the frame's one-colour
    #: light where the frame was measured on that light's luma
    #: (:func:`blurtrack.detect.image.to_gray`); None: a gray frame, or the brightest channel.
    light_bgr: tuple[float, float, float] | None = None
    #: ``(N,)`` the gyro check's start-to-end vector residual of each streak (px, against the
    #: corrected prediction; NaN: not checked); empty: the frame was not checked
    #: (:func:`blurtrack.detect.gyro.gyrotrust.check_frames`).
    gyro_residual_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: The frame's model error that its check's tolerances follow (px;
    #: :func:`blurtrack.detect.gyro.framecheck.frame_tolerances`); NaN: not measured.
    gyro_model_error_px: float = float("nan")

    def __len__(self) -> int:
        return int(self.end_a.shape[0])

    def __getstate__(self) -> dict[str, Any]:
        # Workers send frames back pickled: the per-streak lines as one array each (a few
        # hundred small arrays pickle several times slower), unpacked as views.
        state = dict(self.__dict__)
        state["points"] = _pack(self.points)
        state["profile"] = _pack(self.profile)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        state["points"] = _unpack(state["points"])
        state["profile"] = _unpack(state["profile"])
        self.__dict__.update(state)

    def set_verdict(self, ok: np.ndarray, reason: np.ndarray) -> None:
        """Replace ``quality``'s ``quality_ok`` and ``reason`` (``(N,)`` each; the checks that
        follow the frame's own quality: the gyro's, a photograph's whole lights)."""
        assert self.quality is not None
        q = list(self.quality)
        q[2], q[4] = ok, reason
        self.quality = tuple(q)

    def reverse(self, which: np.ndarray) -> None:
        """Swap ends A and B (and reverse the lines) of the streaks where ``which`` is True."""
        flip = np.flatnonzero(which)
        if flip.size == 0:
            return
        a = self.end_a[flip]
        self.end_a[flip] = self.end_b[flip]
        self.end_b[flip] = a
        self.plateau[flip] = self.plateau[flip, ::-1]
        # Reversed views: the cells are only read (the table rounds them into new arrays).
        for i in flip.tolist():
            self.points[i] = self.points[i][::-1]
            self.profile[i] = self.profile[i][::-1]
        if self.evidence is not None:
            self.evidence.end_light[flip] = self.evidence.end_light[flip, ::-1]


def _pack(arrays: list[np.ndarray]) -> Any:
    """Per-streak arrays as ``(flat, sizes)`` when they share a dtype and trailing shape
    (they do: float64 lines, float64 profiles), else the list itself."""
    if not arrays or len({(a.dtype, a.shape[1:]) for a in arrays}) != 1:
        return list(arrays)
    return np.concatenate(arrays), np.fromiter(map(len, arrays), np.int64, len(arrays))


def _unpack(packed: Any) -> list[np.ndarray]:
    """The inverse of :func:`_pack`: views of the flat array, one per streak."""
    if isinstance(packed, list):
        return packed
    flat, sizes = packed
    return split_at(flat, np.cumsum(sizes)[:-1])


def _self_crossing(points: np.ndarray, min_arc_px: float) -> bool:
    """Whether a ~1 px sampled centre line comes back within 1.5 px of itself after more than
    ``min_arc_px`` of arc (a loop)."""
    n = len(points)
    if n < 3:
        return False
    gap = int(np.floor(min_arc_px)) + 1  # index separation beyond min_arc_px (~1 px apart)
    for a in range(0, n, 512):  # exhaustive, in blocks of rows
        q = points[a : a + 512]
        d2 = (q[:, None, 0] - points[None, :, 0]) ** 2 + (q[:, None, 1] - points[None, :, 1]) ** 2
        i, j = np.nonzero(d2 <= 1.5**2)
        if np.any(np.abs(i + a - j) >= gap):
            return True
    return False


def _first_lines(
    comps: Components, polylines: list[np.ndarray], folded: np.ndarray, spur: float
) -> LineSet:
    """Coarse lines of the first pass: the axis polylines, skeleton paths of folded
    components, 1 px segments for round spots."""
    # Round spots (one point, or ends that coincide) get a 1 px segment; tested for all lines
    # at once, since the loop below runs once per component.
    sizes = np.fromiter(map(len, polylines), np.int64, len(polylines))
    last = np.cumsum(sizes) - 1
    flat = np.concatenate(polylines)
    spot = (sizes < 2) | (np.abs(flat[last] - flat[last - sizes + 1]).sum(axis=1) < 1e-9)
    if not (spot.any() or folded.any()):  # the usual frame: every line as it is
        n = len(polylines)
        return LineSet(Ragged(flat, sizes), list(range(n)), [False] * n, [False] * n)
    ls = LineSet([], [], [], [])
    lines: list[np.ndarray] = []
    for i, (poly, fold) in enumerate(zip(polylines, folded.tolist(), strict=True)):
        if not fold:
            if spot[i]:
                poly = np.stack([poly[0] - [0.5, 0.0], poly[0] + [0.5, 0.0]])
            ls.owner.append(i)
            lines.append(poly)
            ls.crossing.append(False)
            ls.looped.append(False)
            continue
        x, y, w, h = comps.boxes[i]
        mask = comps.labels[y : y + h, x : x + w] == comps.ids[i]
        paths = trace_paths(np.pad(mask, 1), spur, spur)
        for path in paths:
            ls.owner.append(i)
            lines.append(path.points + np.array([x - 1.0, y - 1.0]))
            ls.crossing.append(path.shares_junction or len(paths) > 1)
            ls.looped.append(path.self_crossing)
    ls.lines = lines
    return ls


def _empty(
    shape: tuple[int, int], sigma_c: float, noise: float, hot: int, sat_frac: float
) -> FrameStreaks:
    z2 = np.zeros((0, 2))
    return FrameStreaks(
        shape,
        z2,
        z2.copy(),
        z2.copy(),
        z2.copy(),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0),
        [],
        [],
        {k: np.zeros(0, bool) for k in FLAG_NAMES},
        sigma_c,
        noise,
        hot,
        saturated_fraction=sat_frac,
    )


def detect_frame(image: np.ndarray, params: DetectParams | None = None) -> FrameStreaks:
    """Find and measure every streak of one frame.

    Args:
        image: ``(H, W)`` or ``(H, W, 3|4)`` uint8/uint16 frame as stored.
        params: detection parameters (defaults if None).
    Returns:
        The frame's streaks (possibly none: a frame without dots is a valid result here; the
        session level decides whether that is an error).
    """
    keep_heap()  # once per process: no page faults for per-frame buffers
    return detect_prepared(*prepare_and_segment(image, params or DetectParams()))


def detect_prepared(prep: PreparedFrame, ctx: FrameContext) -> FrameStreaks:
    """:func:`detect_frame` of a frame already prepared (``prep``) and segmented (``ctx``,
    whose ``params`` it uses: :func:`blurtrack.detect.context.prepare_and_segment`), for
    callers that read the context again."""
    p = ctx.params
    sat_frac = float(np.count_nonzero(prep.saturated)) / (ctx.shape[0] * ctx.shape[1])
    psf_guess = p.psf_sigma_px if p.psf_sigma_px is not None else 1.5
    sigma_c = float(np.sqrt(psf_guess**2 + p.smooth_sigma_px**2 + 1.0 / 12.0))
    if ctx.comps.ids.size == 0:
        fs = _empty(ctx.shape, sigma_c, prep.noise, prep.hot_pixels, sat_frac)
    else:
        m, folded = _first_pass(ctx, sigma_c)
        if p.separate and len(m):
            m = _separated(ctx, m, folded)
        if len(m) == 0:
            fs = _empty(ctx.shape, m.sigma_c, prep.noise, prep.hot_pixels, sat_frac)
        else:
            fs = _frame_streaks(ctx, m, prep.noise, prep.hot_pixels, sat_frac)
    fs.light_bgr = prep.light_bgr
    return fs


def _first_pass(ctx: FrameContext, sigma_c: float) -> tuple[Measured, np.ndarray]:
    """The first pass: each component's coarse line(s) measured on the frame (``sigma_c``:
    the guess of the cross-section sigma; measured unless ``psf_sigma_px`` is fixed), and
    the ``(C,)`` bool components whose lines the skeleton tracer took (folded)."""
    comps = ctx.comps
    polylines, folded = axis_polylines(ctx.smooth, comps, sigma_c)
    ls = _first_lines(comps, polylines, folded, 2.0 * sigma_c + 3.0)
    m = measure_lines(ctx, ls, sigma_c, ctx.params.psf_sigma_px is None)
    m.looped = np.array(
        [
            lp or (folded[o] and _self_crossing(pts, 4.0 * m.sigma_c))
            for lp, o, pts in zip(m.looped.tolist(), m.own.tolist(), m.points, strict=True)
        ],
        bool,
    )
    return m, folded


def _separated(ctx: FrameContext, m: Measured, folded: np.ndarray) -> Measured:
    """Template separation (:func:`~blurtrack.detect.separation.separate.separate`), the
    remnant spots dropped, and with whole-component references the anchored placements on
    fragments (:func:`~blurtrack.detect.separation.anchored.anchored`)."""
    sep = separate(ctx, m, folded)
    if sep.streaks is not None and sep.replaced is not None:
        m = _combine(m, ~sep.replaced[m.own], sep.streaks)
    if sep.field is None:
        return m
    # Every dot draws about the same curve: a spot far shorter than the local consensus
    # inside the frame is a remnant (of a chain, a blob), not a dot's streak.
    c = np.hypot(*sep.field.at(m.time_mid).T)
    inside = ~ctx.clipped(m.end_a, m.end_b)
    sp = ctx.params.separation
    m = _combine(m, ~(inside & (c >= sp.spot_min_px) & (m.length_px < sp.spot_fraction * c)))
    if sep.refs is not None and sep.good is not None and len(m):
        m, _ = anchored(ctx, m, sep.refs, sep.good, sep.field)
    return m


def _frame_streaks(
    ctx: FrameContext, m: Measured, noise: float, hot_pixels: int, sat_frac: float
) -> FrameStreaks:
    """The frame's measured streaks with their flags and evidence (``noise``, ``hot_pixels``,
    ``sat_frac``: as :class:`FrameStreaks` reports them)."""
    p, comps, sigma_c = ctx.params, ctx.comps, m.sigma_c
    width = m.width_px
    flags = {
        "clipped": ctx.clipped(m.end_a, m.end_b),
        "saturated": m.saturated,
        "crossing": m.crossing,
        "merged": ctx.merged(width, sigma_c),
        "looped": m.looped,
        "faint": comps.peaks[m.own] < p.faint_snr * ctx.noise_smooth,
    }
    evidence = assess(ctx, m.points, m.profile, m.plateau, width, sigma_c)
    return FrameStreaks(
        shape=ctx.shape,
        end_a=m.end_a,
        end_b=m.end_b,
        time_mid=m.time_mid,
        plateau=m.plateau,
        length_px=m.length_px,
        width_px=width,
        snr=comps.peaks[m.own] / ctx.noise_smooth,
        points=m.points,
        profile=m.profile,
        flags=flags,
        sigma_c_px=sigma_c,
        noise=noise,
        hot_pixels=hot_pixels,
        short=m.short,
        saturated_fraction=sat_frac,
        evidence=evidence,
    )
