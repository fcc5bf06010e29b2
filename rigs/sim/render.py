"""Time-integrated rendering of laser-dot streaks, and the sensor's radiometry.

Rendering (linear photo-electrons): each dot's light is integrated over its own active time,
split into slots of equal arc length so that consecutive positions are at most ``substep_px``
apart (fast stretches get more slots than slow ones; equal-time slots would waste most samples
on the slow parts). Every slot splats a small Gaussian patch whose per-pixel weights are the
Gaussian's integral over the pixel (erf differences, separable in x and y) times, per patch row,
the overlap of the slot with that row's exposure window ``[t + readout · r / H, + exposure]``:
a rolling shutter is resolved row by row. Patches are accumulated with ``np.bincount``
(vectorised; OpenCV has no sub-pixel weighted splat).

Radiometry (:func:`expose`): ambient light, Poisson shot noise, Gaussian read noise, full-well
saturation, then quantisation to 8 or 16 bits; real-optics effects around it
(:mod:`rigs.sim.optics`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.special import ndtr

from blurtrack.geometry.camera import Camera
from rigs.sim.dots import TrueFrameStreaks, dot_pixels
from rigs.sim.motion import TrueMotion
from rigs.sim.optics import Optics, bloom, demosaic_and_encode, field_blur, mosaic, speckle

#: Patch half-width in dot sigmas (the Gaussian beyond it holds < 5e-4 of the light per side).
PATCH_SIGMAS = 3.5
#: Splat entries per vectorised chunk (bounds memory to ~20 MB).
CHUNK_ENTRIES = 2_000_000
#: Shot noise is drawn exactly (Poisson) below this mean, as its Gaussian limit above (e-).
POISSON_EXACT_BELOW_E = 100.0
#: Coarse samples per streak from which its render slots are laid out by arc length.
COARSE_SAMPLES = 256
#: Fewest render slots per streak.
MIN_SLOTS = 4


def patch_radius(sigma_px: float) -> int:
    return max(1, math.ceil(PATCH_SIGMAS * sigma_px))


def splat(
    out: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    sigma_px: float,
    row_weight: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> None:
    """Add Gaussian patches centred at ``(u, v) (S,)`` into ``out (H, W)`` in place.

    ``row_weight(rows (s, P), sel) -> (s, P)`` gives each sample's weight per patch row (energy
    in electrons for that row); ``sel (s,)`` indexes the samples of ``u``/``v`` being processed.
    Patches are accumulated in a frame padded by twice the patch radius, so that no index of a
    patch touching the image needs clipping, and cropped at the end.
    """
    H, W = out.shape
    R = patch_radius(sigma_px)
    P = 2 * R + 1
    pad = 2 * R
    Wp = W + 2 * pad
    offs = np.arange(-R, R + 1)
    pattern = (offs[:, None] * Wp + offs[None, :]).ravel()
    cu = np.floor(u + 0.5).astype(np.int64)
    cv = np.floor(v + 0.5).astype(np.int64)
    # Patches of these centres touch the image; others are skipped.
    keep = np.flatnonzero((cu >= -R) & (cu < W + R) & (cv >= -R) & (cv < H + R))
    acc = np.zeros((H + 2 * pad) * Wp)
    step = max(1, CHUNK_ENTRIES // (P * P))
    # Reused buffers: fresh multi-MB arrays per chunk cost more in page faults than the maths.
    w_buf = np.empty((step, P, P))
    i_buf = np.empty((step, P * P), dtype=np.int64)
    for a in range(0, keep.size, step):
        k = keep[a : a + step]
        m = k.size
        uu, vv = u[k][:, None], v[k][:, None]
        px = cu[k][:, None] + offs
        py = cv[k][:, None] + offs
        gx = ndtr((px + 0.5 - uu) / sigma_px) - ndtr((px - 0.5 - uu) / sigma_px)
        wy = (ndtr((py + 0.5 - vv) / sigma_px) - ndtr((py - 0.5 - vv) / sigma_px)) * row_weight(
            py, k
        )
        base = (cv[k] + pad) * Wp + (cu[k] + pad)
        idx = np.add(base[:, None], pattern[None, :], out=i_buf[:m])
        w = np.multiply(wy[:, :, None], gx[:, None, :], out=w_buf[:m])
        lo = int(base.min()) - pattern[-1]
        flat = idx.ravel()
        flat -= lo
        binned = np.bincount(flat, weights=w.ravel())
        acc[lo : lo + binned.size] += binned
    out += acc.reshape(H + 2 * pad, Wp)[pad : pad + H, pad : pad + W]


def arc_length_slots(
    t_coarse: np.ndarray, p_coarse: np.ndarray, substep_px: float, min_slots: int = MIN_SLOTS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split each dot's time window into slots over which it moves at most ``substep_px``.

    Args:
        t_coarse: ``(J, M + 1)`` increasing times per dot spanning its window.
        p_coarse: ``(J, M + 1, 2)`` its positions there (the path is taken as piecewise linear
            between them).

    Returns:
        ``(dot (S,), t_lo (S,), t_hi (S,))``: for every slot, the row of its dot and its time
        bounds; slots split each path into equal arc lengths (equal times where it stands
        still), so fast stretches get more slots than slow ones.
    """
    J, M1 = t_coarse.shape
    seg = np.nan_to_num(np.linalg.norm(np.diff(p_coarse, axis=1), axis=2))
    length = seg.sum(axis=1)
    # A tiny time-proportional term keeps the arc-length axis strictly increasing.
    tiny = 1e-6 * substep_px
    frac = (t_coarse - t_coarse[:, :1]) / (t_coarse[:, -1:] - t_coarse[:, :1])
    arc = np.concatenate([np.zeros((J, 1)), np.cumsum(seg, axis=1)], axis=1) + tiny * frac
    total = arc[:, -1]
    n = np.maximum(np.ceil(length / substep_px).astype(np.int64), min_slots)
    # Slot boundaries k / n_j of each dot's arc (k = 0..n_j), located by one global search.
    start = np.concatenate([[0], np.cumsum(n + 1)[:-1]])
    dot_b = np.repeat(np.arange(J), n + 1)
    k = np.arange(dot_b.size) - start[dot_b]
    target = k / n[dot_b] * total[dot_b]
    big = float(total.max()) * 2 + 1.0
    glob = (arc + big * np.arange(J)[:, None]).ravel()
    pos = np.clip(
        np.searchsorted(glob, target + big * dot_b, side="right") - 1,
        dot_b * M1,
        dot_b * M1 + M1 - 2,
    )
    a0, a1 = glob[pos] - big * dot_b, glob[pos + 1] - big * dot_b
    tc = t_coarse.ravel()
    f = np.clip((target - a0) / (a1 - a0), 0.0, 1.0)
    bounds = tc[pos] + f * (tc[pos + 1] - tc[pos])
    last = np.cumsum(n + 1) - 1  # index of each dot's final boundary
    keep = np.ones(bounds.size, bool)
    keep[last] = False
    return dot_b[keep], bounds[keep], bounds[np.flatnonzero(keep) + 1]


def render_streaks(
    motion: TrueMotion,
    camera: Camera,
    directions: np.ndarray,
    streaks: TrueFrameStreaks,
    frame_t_s: float,
    exposure_s: float,
    flux_eps: float,
    sigma_px: float,
    substep_px: float,
) -> np.ndarray:
    """Mean photo-electrons ``(H, W)`` that the dots deposit in one rolling-shutter frame."""
    W, H = camera.resolution
    out = np.zeros((H, W))
    R = patch_radius(sigma_px)
    ro = camera.readout_s
    # Rows of a patch start up to ro * R / H apart: widen each dot's window to cover them.
    pad = 1.5 * ro * (R + 1) / H
    margin = R + 1.0
    x, y = streaks.path[..., 0], streaks.path[..., 1]
    near = np.all(np.isfinite(x), axis=1) & np.any(
        (x >= -margin) & (x <= W - 1 + margin) & (y >= -margin) & (y <= H - 1 + margin), axis=1
    )
    idx = np.flatnonzero(near)
    if idx.size == 0 or flux_eps == 0:
        return out
    lo = streaks.t_start_s[idx] - pad
    hi = streaks.t_end_s[idx] + pad
    frac = np.linspace(0.0, 1.0, COARSE_SAMPLES + 1)
    t_coarse = lo[:, None] + (hi - lo)[:, None] * frac
    p_coarse = dot_pixels(
        motion, camera, directions, t_coarse.ravel(), np.repeat(idx, frac.size)
    ).reshape(idx.size, frac.size, 2)
    which, t0, t1 = arc_length_slots(t_coarse, p_coarse, substep_px)
    pos = dot_pixels(motion, camera, directions, (t0 + t1) / 2, idx[which])

    def row_weight(rows: np.ndarray, sel: np.ndarray) -> np.ndarray:
        r0 = frame_t_s + ro * rows / H
        overlap = np.minimum(t1[sel][:, None], r0 + exposure_s) - np.maximum(t0[sel][:, None], r0)
        return flux_eps * np.clip(overlap, 0.0, None)

    splat(out, pos[:, 0], pos[:, 1], sigma_px, row_weight)
    return out


def render_points(
    shape: tuple[int, int], pixels: np.ndarray, energy_e: float, sigma_px: float
) -> np.ndarray:
    """Mean photo-electrons ``(H, W)`` of motionless dots at ``pixels (J, 2)``, each
    ``energy_e`` electrons in all (the sharp frame)."""
    out = np.zeros(shape)
    px = np.asarray(pixels, dtype=float)
    px = px[np.all(np.isfinite(px), axis=1)]
    if px.size:
        splat(
            out,
            px[:, 0],
            px[:, 1],
            sigma_px,
            lambda rows, sel: np.full(rows.shape, float(energy_e)),
        )
    return out


def ambient_map(width: int, height: int, level_e: float, vignetting: float) -> np.ndarray:
    """Ambient electrons ``(H, W)`` (float32): ``level (1 - vignetting r² / r_corner²)``, ``r``
    the distance from the image centre."""
    x = (np.arange(width) - (width - 1) / 2) / ((width - 1) / 2 or 1)
    y = (np.arange(height) - (height - 1) / 2) / ((height - 1) / 2 or 1)
    r2 = (x[None, :] ** 2 * width**2 + y[:, None] ** 2 * height**2) / (width**2 + height**2)
    return (level_e * (1.0 - vignetting * r2)).astype(np.float32)


def expose(
    signal_e: np.ndarray,
    ambient_e: float | np.ndarray,
    full_well_e: float,
    read_noise_e: float,
    shot_noise: bool,
    bit_depth: int,
    rng: np.random.Generator | None,
    optics: Optics | None = None,
) -> np.ndarray:
    """Sensor model: mean electrons ``(H, W)`` -> ``uint8``/``uint16`` image.

    Shot noise on signal + ambient and Gaussian read noise, then saturation at the full well
    (where the ADC clips), linear scaling of ``[0, full_well]`` to the digital range, rounding.
    Shot noise is exact Poisson below ``POISSON_EXACT_BELOW_E`` electrons and its Gaussian limit
    ``N(λ, λ)`` above (skewness < 0.1 there, far below one digital step; it is ~5x faster and
    lets shot and read noise share one normal draw). ``rng = None`` gives the noise-free image.
    ``optics`` (:mod:`rigs.sim.optics`): speckle, field-varying lens blur, chromatic fringes and
    a Bayer mosaic before the sensor, blooming at its full well, demosaicing and JPEG after it;
    a colour sensor gives ``(H, W, 3)`` BGR frames.
    """
    o = optics or Optics()
    dots = field_blur(speckle(np.asarray(signal_e, dtype=np.float32), o, rng), o)
    e = mosaic(dots, ambient_e, o) if o.colour else dots + np.asarray(ambient_e, np.float32)
    if rng is not None and (shot_noise or read_noise_e > 0):
        var = (
            e + np.float32(read_noise_e**2)
            if shot_noise
            else np.full(e.shape, read_noise_e**2, np.float32)
        )
        noisy = e + np.sqrt(var) * rng.standard_normal(e.shape, dtype=np.float32)
        if shot_noise:
            low = e < POISSON_EXACT_BELOW_E
            if np.any(low):
                lam = e[low]
                noisy[low] = rng.poisson(lam).astype(np.float32) + np.float32(
                    read_noise_e
                ) * rng.standard_normal(lam.shape, dtype=np.float32)
        e = noisy
    e = bloom(e, full_well_e, o)
    top = (1 << bit_depth) - 1
    dn = np.clip(np.rint(e * np.float32(top / full_well_e)), 0, top)
    return demosaic_and_encode(dn.astype(np.uint8 if bit_depth == 8 else np.uint16), o)
