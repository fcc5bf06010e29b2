"""Time-integrated rendering of laser-dot streaks, and the sensor's radiometry.

Rendering (linear photo-electrons): each dot's light is integrated over its own active time,
sampled so that consecutive positions are at most ``substep_px`` apart. Every sample splats a
small Gaussian patch whose per-pixel weights are the Gaussian's integral over the pixel (erf
differences, separable in x and y) times, per patch row, the overlap of the sample's time slot
with that row's exposure window ``[t + readout · r / H, + exposure]``: a rolling shutter is
resolved row by row. Patches are accumulated with ``np.bincount`` (vectorised; OpenCV has no
sub-pixel weighted splat).

Radiometry (:func:`expose`): ambient light, Poisson shot noise, Gaussian read noise, full-well
saturation, then quantisation to 8 or 16 bits.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.special import ndtr

from blurtrack.camera import Camera
from rigs.sim.dots import FrameStreaks, dot_pixels
from rigs.sim.motion import TrueMotion

#: Patch half-width in dot sigmas (the Gaussian beyond it holds < 5e-4 of the light per side).
PATCH_SIGMAS = 3.5
#: Splat entries per vectorised chunk (bounds memory to ~100 MB).
CHUNK_ENTRIES = 4_000_000
#: Shot noise is drawn exactly (Poisson) below this mean, as its Gaussian limit above (e-).
POISSON_EXACT_BELOW_E = 100.0
#: Coarse samples per streak used to choose the number of render sub-steps.
COARSE_SAMPLES = 48


def patch_radius(sigma_px: float) -> int:
    return max(1, math.ceil(PATCH_SIGMAS * sigma_px))


def splat(out: np.ndarray, u: np.ndarray, v: np.ndarray, sigma_px: float,
          row_weight: Callable[[np.ndarray, slice], np.ndarray]) -> None:
    """Add Gaussian patches centred at ``(u, v) (S,)`` into ``out (H, W)`` in place.

    ``row_weight(rows (s, P), chunk) -> (s, P)`` gives each sample's weight per patch row (energy
    in electrons for that row); ``chunk`` selects the samples of ``u``/``v`` being processed.
    """
    H, W = out.shape
    R = patch_radius(sigma_px)
    P = 2 * R + 1
    offs = np.arange(-R, R + 1)
    step = max(1, CHUNK_ENTRIES // (P * P))
    flat = out.reshape(-1)
    for a in range(0, u.size, step):
        sl = slice(a, min(a + step, u.size))
        uu, vv = u[sl], v[sl]
        px = np.floor(uu + 0.5).astype(np.int64)[:, None] + offs
        py = np.floor(vv + 0.5).astype(np.int64)[:, None] + offs
        gx = ndtr((px + 0.5 - uu[:, None]) / sigma_px) - ndtr((px - 0.5 - uu[:, None]) / sigma_px)
        gy = ndtr((py + 0.5 - vv[:, None]) / sigma_px) - ndtr((py - 0.5 - vv[:, None]) / sigma_px)
        wy = gy * row_weight(py, sl)
        gx = np.where((px >= 0) & (px < W), gx, 0.0)
        wy = np.where((py >= 0) & (py < H), wy, 0.0)
        idx = np.clip(py, 0, H - 1)[:, :, None] * W + np.clip(px, 0, W - 1)[:, None, :]
        w = wy[:, :, None] * gx[:, None, :]
        flat += np.bincount(idx.ravel(), weights=w.ravel(), minlength=H * W)


def render_streaks(motion: TrueMotion, camera: Camera, directions: np.ndarray,
                   streaks: FrameStreaks, frame_t_s: float, exposure_s: float,
                   flux_eps: float, sigma_px: float, substep_px: float) -> np.ndarray:
    """Mean photo-electrons ``(H, W)`` that the dots deposit in one rolling-shutter frame."""
    W, H = camera.resolution
    out = np.zeros((H, W))
    R = patch_radius(sigma_px)
    ro = camera.readout_s
    # Rows of a patch start up to ro * R / H apart: widen each dot's window to cover them.
    pad = 1.5 * ro * (R + 1) / H
    margin = R + 1.0
    x, y = streaks.path[..., 0], streaks.path[..., 1]
    near = np.any(np.isfinite(x) & (x >= -margin) & (x <= W - 1 + margin)
                  & (y >= -margin) & (y <= H - 1 + margin), axis=1)
    idx = np.flatnonzero(near)
    if idx.size == 0 or flux_eps == 0:
        return out
    lo = streaks.t_start_s[idx] - pad
    hi = streaks.t_end_s[idx] + pad
    frac = np.linspace(0.0, 1.0, COARSE_SAMPLES + 1)
    coarse = dot_pixels(motion, camera, directions,
                        (lo[:, None] + (hi - lo)[:, None] * frac).ravel(),
                        np.repeat(idx, frac.size)).reshape(idx.size, frac.size, 2)
    seg = np.nanmax(np.linalg.norm(np.diff(coarse, axis=1), axis=2))
    n = max(16, math.ceil(COARSE_SAMPLES * float(np.nan_to_num(seg)) / substep_px))
    dt = (hi - lo) / n                                   # (J',) each dot's sub-step length
    t = lo[:, None] + dt[:, None] * (np.arange(n) + 0.5)  # (J', n) sub-step midpoints
    pos = dot_pixels(motion, camera, directions, t.ravel(), np.repeat(idx, n))
    ok = np.all(np.isfinite(pos), axis=1)
    ts = t.ravel()[ok]
    dts = np.repeat(dt, n)[ok]

    def row_weight(rows: np.ndarray, sl: slice) -> np.ndarray:
        tt, hh = ts[sl][:, None], dts[sl][:, None] / 2
        r0 = frame_t_s + ro * rows / H
        overlap = np.minimum(tt + hh, r0 + exposure_s) - np.maximum(tt - hh, r0)
        return flux_eps * np.clip(overlap, 0.0, None)

    splat(out, pos[ok, 0], pos[ok, 1], sigma_px, row_weight)
    return out


def render_points(shape: tuple[int, int], pixels: np.ndarray, energy_e: float,
                  sigma_px: float) -> np.ndarray:
    """Mean photo-electrons ``(H, W)`` of motionless dots at ``pixels (J, 2)``, each
    ``energy_e`` electrons in all (the sharp frame)."""
    out = np.zeros(shape)
    px = np.asarray(pixels, dtype=float)
    px = px[np.all(np.isfinite(px), axis=1)]
    if px.size:
        splat(out, px[:, 0], px[:, 1], sigma_px,
              lambda rows, sl: np.full(rows.shape, float(energy_e)))
    return out


def expose(signal_e: np.ndarray, ambient_e: float, full_well_e: float, read_noise_e: float,
           shot_noise: bool, bit_depth: int, rng: np.random.Generator | None) -> np.ndarray:
    """Sensor model: mean electrons ``(H, W)`` -> ``uint8``/``uint16`` image.

    Shot noise on signal + ambient and Gaussian read noise, then saturation at the full well
    (where the ADC clips), linear scaling of ``[0, full_well]`` to the digital range, rounding.
    Shot noise is exact Poisson below ``POISSON_EXACT_BELOW_E`` electrons and its Gaussian limit
    ``N(λ, λ)`` above (skewness < 0.1 there, far below one digital step; it is ~5x faster and
    lets shot and read noise share one normal draw). ``rng = None`` gives the noise-free image.
    """
    e = (np.asarray(signal_e, dtype=np.float32) + np.float32(ambient_e))
    if rng is not None and (shot_noise or read_noise_e > 0):
        var = e + np.float32(read_noise_e ** 2) if shot_noise else \
            np.full(e.shape, read_noise_e ** 2, np.float32)
        noisy = e + np.sqrt(var) * rng.standard_normal(e.shape, dtype=np.float32)
        if shot_noise:
            low = e < POISSON_EXACT_BELOW_E
            if np.any(low):
                lam = e[low]
                noisy[low] = (rng.poisson(lam).astype(np.float32)
                              + np.float32(read_noise_e) * rng.standard_normal(
                                  lam.shape, dtype=np.float32))
        e = noisy
    top = (1 << bit_depth) - 1
    dn = np.clip(np.rint(e * np.float32(top / full_well_e)), 0, top)
    return dn.astype(np.uint8 if bit_depth == 8 else np.uint16)
