"""Detection in one frame: from a stored image to measured, not yet oriented, streaks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from blurtrack.detect.centreline import raw_profiles, refine_lines, trim_lines
from blurtrack.detect.endpoints import fit_edges, unclip_profiles
from blurtrack.detect.gaps import split_at_gaps
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.memory import keep_frame_buffers
from blurtrack.detect.params import DetectParams
from blurtrack.detect.ragged import Ragged, to_matrix
from blurtrack.detect.segment import Components, axis_polylines, find_components
from blurtrack.detect.skeleton import trace_paths

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

    def __len__(self) -> int:
        return int(self.end_a.shape[0])

    def reverse(self, which: np.ndarray) -> None:
        """Swap ends A and B (and reverse the lines) of the streaks where ``which`` is True."""
        for i in np.flatnonzero(which):
            self.end_a[i], self.end_b[i] = self.end_b[i].copy(), self.end_a[i].copy()
            self.plateau[i] = self.plateau[i][::-1].copy()
            self.points[i] = self.points[i][::-1].copy()
            self.profile[i] = self.profile[i][::-1].copy()


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


def _saturated_components(comps: Components, saturated: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: which kept components contain saturated pixels (from their pixel
    lists: a saturated pixel is bright enough to lie in a component)."""
    if comps.ids.size == 0:
        return np.zeros(0, bool)
    return np.maximum.reduceat(saturated[comps.ys, comps.xs], comps.starts)


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
    p = params or DetectParams()
    keep_frame_buffers()  # once per process: no page faults for per-frame buffers
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    H, W = prep.signal.shape
    sat_frac = float(np.count_nonzero(prep.saturated)) / (H * W)
    psf_guess = p.psf_sigma_px if p.psf_sigma_px is not None else 1.5
    sigma_c = sigma_guess = float(np.sqrt(psf_guess**2 + p.smooth_sigma_px**2 + 1.0 / 12.0))
    threshold = max(p.threshold_snr * prep.noise_smooth, p.min_threshold)
    comps = find_components(prep.smooth, threshold, p.min_area_px, p.max_streaks)
    if comps.ids.size == 0:
        return _empty((H, W), sigma_c, prep.noise, prep.hot_pixels, sat_frac)
    polylines, folded = axis_polylines(prep.smooth, comps, sigma_c)
    owner: list[int] = []  # component index of each line
    lines: list[np.ndarray] = []
    crossing: list[bool] = []
    looped: list[bool] = []
    spur = 2.0 * sigma_c + 3.0
    # Round spots (one point, or ends that coincide) get a 1 px segment; tested for all lines
    # at once, since the loop below runs once per component.
    sizes = np.fromiter(map(len, polylines), np.int64, len(polylines))
    last = np.cumsum(sizes) - 1
    flat = np.concatenate(polylines)
    spot = (sizes < 2) | (np.abs(flat[last] - flat[last - sizes + 1]).sum(axis=1) < 1e-9)
    line_input: Ragged | list[np.ndarray] = lines
    if not (spot.any() or folded.any()):  # the usual frame: every line as it is
        owner = list(range(len(polylines)))
        crossing = looped = [False] * len(polylines)
        line_input = Ragged(flat, sizes)
    else:
        for i, (poly, fold) in enumerate(zip(polylines, folded.tolist(), strict=True)):
            if not fold:
                if spot[i]:
                    poly = np.stack([poly[0] - [0.5, 0.0], poly[0] + [0.5, 0.0]])
                owner.append(i)
                lines.append(poly)
                crossing.append(False)
                looped.append(False)
                continue
            x, y, w, h = comps.boxes[i]
            mask = comps.labels[y : y + h, x : x + w] == comps.ids[i]
            paths = trace_paths(np.pad(mask, 1), spur, spur)
            for path in paths:
                owner.append(i)
                lines.append(path.points + np.array([x - 1.0, y - 1.0]))
                crossing.append(path.shares_junction or len(paths) > 1)
                looped.append(path.self_crossing)
    ref = refine_lines(
        prep.smooth, line_input, sigma_c, prep.saturation if prep.saturated.any() else None
    )
    ref, parent = split_at_gaps(ref)
    owner = [owner[k] for k in parent]
    crossing = [crossing[k] for k in parent]
    looped = [looped[k] for k in parent]
    finite = ref.width[np.isfinite(ref.width)]
    if p.psf_sigma_px is None and finite.size:
        sigma_c = float(np.median(finite))
    lens = ref.lines.sizes
    A = to_matrix(ref.profile, lens)
    line_sat = np.zeros(lens.size, bool)
    if prep.saturated.any():
        sat_comp = _saturated_components(comps, prep.saturated)
        line_sat = sat_comp[np.asarray(owner)]
        clean = ref.width[~line_sat]
        clean = clean[np.isfinite(clean)]
        # Saturated streaks: width from the unsaturated ones if there are enough of them,
        # else from everyone's flanks (refine_lines measured clipped sections there).
        if clean.size < 8:
            clean = ref.width[np.isfinite(ref.width)]
        sig_c = float(np.median(clean)) if clean.size else sigma_guess
        sigma_raw = float(np.sqrt(max(sig_c**2 - p.smooth_sigma_px**2, 0.25)))
        if p.psf_sigma_px is None:
            sigma_c = sig_c
        # Clipping happens before smoothing, so undo it on profiles of the unsmoothed signal
        # (there the clipped cross-section integral is an exact function of the true one).
        if line_sat.any():  # only saturated lines are sampled (rows past their ends stay 0)
            sat_lines = Ragged(ref.lines.points[line_sat[ref.lines.line_of]], lens[line_sat])
            raw = to_matrix(raw_profiles(prep.signal, sat_lines, sigma_c), sat_lines.sizes)
            A[line_sat, : raw.shape[1]] = unclip_profiles(raw, prep.saturation, sigma_raw)
    # Raw profiles are sampled bilinearly, which blurs by about 1/6 px^2 more.
    edge_sigma = np.where(
        line_sat, np.sqrt(sigma_raw**2 + 1.0 / 6.0) if line_sat.any() else sigma_c, sigma_c
    )
    fit = fit_edges(A, lens, edge_sigma / ref.step)
    pos_a = np.where(fit.valid, fit.pos_a, 0.0)
    pos_b = np.where(fit.valid, fit.pos_b, 1.0)
    trimmed = trim_lines(ref, pos_a, pos_b, edge_sigma / ref.step)
    keep = np.flatnonzero(fit.valid)
    if keep.size == 0:
        return _empty((H, W), sigma_c, prep.noise, prep.hot_pixels, sat_frac)
    own = np.asarray(owner)[keep]
    end_a = trimmed.end_a[keep]
    end_b = trimmed.end_b[keep]
    ends = np.stack([end_a, end_b], axis=1)
    m_px = p.border_margin_px
    near = (
        (ends[..., 0] < m_px)
        | (ends[..., 0] > W - 1 - m_px)
        | (ends[..., 1] < m_px)
        | (ends[..., 1] > H - 1 - m_px)
    )
    width = ref.width[keep]
    flags = {
        "clipped": near.any(axis=1),
        "saturated": line_sat[keep],
        "crossing": np.asarray(crossing, bool)[keep],
        "merged": np.isfinite(width) & (width > 1.5 * sigma_c),
        "looped": np.array(
            [
                looped[k] or (folded[owner[k]] and _self_crossing(trimmed.points[k], 4.0 * sigma_c))
                for k in keep
            ],
            bool,
        ),
        "faint": comps.peaks[own] < p.faint_snr * prep.noise_smooth,
    }
    plateau = np.stack([fit.plateau_a, fit.plateau_b], axis=1)[keep]
    return FrameStreaks(
        shape=(H, W),
        end_a=end_a,
        end_b=end_b,
        time_mid=trimmed.time_mid[keep],
        plateau=plateau,
        length_px=trimmed.length_px[keep],
        width_px=width,
        snr=comps.peaks[own] / prep.noise_smooth,
        points=[trimmed.points[k] for k in keep],
        profile=[trimmed.profile[k] for k in keep],
        flags=flags,
        sigma_c_px=sigma_c,
        noise=prep.noise,
        hot_pixels=prep.hot_pixels,
        short=fit.short[keep],
        saturated_fraction=sat_frac,
    )
