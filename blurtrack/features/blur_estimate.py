"""Blur of one image tile measured from the tile alone (no gyro): its power cepstrum compared
with what a blur kernel predicts.

Model: a tile is ``b = k * s`` (kernel ``k``, sharp scene ``s``), so its power spectrum is
``|K|² |S|²`` and its log spectrum the sum ``log|K|² + log|S|²``. Each power spectrum is first
divided by its own mean over directions at each spatial frequency (the scene's ``1/|f|^α``
fall-off, whatever ``α``, goes; an isotropic scene leaves only the kernel's anisotropy). The
inverse transform of the log (the *cepstrum*, :func:`tile_cepstrum`) keeps the smooth scene
term near zero lag, while a straight blur of length ``L`` along ``θ`` (a ``sinc`` with zeros
every ``1/L`` across the blur) leaves pronounced negative peaks at the lags
``±(L cos θ, L sin θ)`` (and fainter ones at multiples). :func:`kernel_cepstrum` computes the
same map for any kernel, and :func:`kernel_score` compares the two maps by normalised
cross-correlation over the annulus ``r_min <= |lag| <= radius`` (the centre, where the scene
sits, is left out): no straight-line assumption, so the curved kernels of real shake can be
scored. :func:`estimate_blur_vector` reads a tile's blur vector as the best-scoring straight
line (sign-free: a cepstrum is symmetric).

Units: pixels of the arrays given (tile and kernel trajectories at the same scale); lags are
``(dx, dy)`` with x to the right and y down; maps are ``(2·radius + 1, 2·radius + 1)`` arrays
indexed ``[radius + dy, radius + dx]``. A kernel's map must be computed on the same FFT grid
(``n``) as the tile's: :func:`fft_size`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from blurtrack.errors import BlurTrackError


class BlurEstimateError(BlurTrackError):
    """A tile, kernel or trajectory that cannot be measured (wrong shape, empty, too small)."""


@dataclass(frozen=True)
class BlurVector:
    """A tile's blur measured from its autocorrelation.

    Attributes:
        vector_px: ``(dx, dy)`` of the blur (its sign is not observable: ``-vector`` is the same).
        length_px: ``|vector|``.
        angle_deg: direction in ``[0, 180)`` degrees, x towards y (image coordinates).
        score: :func:`kernel_score` of that line kernel against the tile.
        margin: ``score`` minus the score of the same line turned by 90°: how much better the
            found direction explains the tile than the perpendicular one.
    """

    vector_px: tuple[float, float]
    length_px: float
    angle_deg: float
    score: float
    margin: float


def _check_tile(tile: np.ndarray, radius: int) -> np.ndarray:
    t = np.asarray(tile, dtype=np.float64)
    if t.ndim != 2 or min(t.shape) < 8:
        raise BlurEstimateError(f"a tile must be a 2-D array of at least 8x8, got {t.shape}")
    if radius < 2 or 2 * radius + 1 > min(t.shape):
        raise BlurEstimateError(
            f"radius {radius} must be >= 2 and leave 2*radius+1 <= the tile's side {min(t.shape)}"
        )
    if not np.all(np.isfinite(t)):
        raise BlurEstimateError("a tile has NaN or infinite values")
    return t


#: Floor added to the direction-normalised power spectrum before the log (the tile's noise
#: and the kernel's ``sinc`` zeros both end there).
LOG_FLOOR = 1e-3
#: Default frequency taper of the log spectrum (cycles/px): see :func:`tile_cepstrum`.
DEFAULT_TAPER = 0.2


def fft_size(tile_shape: tuple[int, ...]) -> int:
    """The square FFT grid side used for a tile of this shape (and for its kernels)."""
    return int(cv2.getOptimalDFTSize(max(int(tile_shape[0]), int(tile_shape[1]))))


def _crop(c: np.ndarray, radius: int) -> np.ndarray:
    n = c.shape[0]
    idx = np.r_[n - radius : n, 0 : radius + 1]
    return c[np.ix_(idx, idx)]


def _cepstrum(F: np.ndarray, radius: int, taper: float | None) -> np.ndarray:
    """Cepstrum map of a square spectrum ``F (n, n)``: power normalised per frequency ring,
    log, weighted by ``exp(-(|f| / taper)²)`` (cycles/px), inverse transform."""
    n = F.shape[0]
    P = np.abs(F) ** 2
    f = np.fft.fftfreq(n)
    ring = np.minimum((np.hypot(f[None, :], f[:, None]) * n).astype(int), n // 2)
    mean = np.bincount(ring.ravel(), P.ravel()) / np.maximum(np.bincount(ring.ravel()), 1)
    W = P / np.maximum(mean[ring], 1e-300)
    logw = np.log(W + LOG_FLOOR)
    if taper is not None:
        logw *= np.exp(-((np.hypot(f[None, :], f[:, None]) / taper) ** 2))
    return _crop(np.fft.ifft2(logw).real, radius)


def tile_cepstrum(
    tile: np.ndarray, radius: int = 32, taper: float | None = DEFAULT_TAPER
) -> np.ndarray | None:
    """Cepstrum map ``(2r+1, 2r+1)`` of a gray tile ``(h, w)`` (any units of intensity).

    The tile minus its mean is Hann-windowed and transformed on the :func:`fft_size` grid.
    ``taper`` (cycles/px): the log spectrum is weighted by ``exp(-(|f| / taper)²)`` so that
    the high frequencies, where a strongly blurred tile holds only noise and the JPEG block
    grid (whose spectral lines print axis-aligned ridges into the map), count little. Pass
    the same to :func:`kernel_cepstrum`; ``None`` keeps every frequency.
    Returns ``None`` for a tile with no texture (windowed variance below 1e-12 of its squared
    mean level, or exactly zero): its blur is undetermined, not a number.
    """
    t = _check_tile(tile, radius)
    win = np.outer(np.hanning(t.shape[0] + 2)[1:-1], np.hanning(t.shape[1] + 2)[1:-1])
    tw = (t - t.mean()) * win
    if float(np.mean(tw**2)) <= 1e-12 * max(float(np.mean(t)) ** 2, 1e-12):
        return None
    n = fft_size(t.shape)
    return _cepstrum(np.fft.fft2(tw, s=(n, n)), radius, taper)


def rasterize(traj: np.ndarray, size: int, samples_per_px: float = 4.0) -> np.ndarray:
    """Blur kernel ``(size, size)``, sum 1, of a trajectory ``(T, 2)`` (px, any origin).

    The trajectory (linear between its samples, traversed at constant speed in its parameter)
    is centred on its midpoint and splatted bilinearly. ``size`` must be odd.

    >>> k = rasterize(np.array([[0.0, 0.0], [4.0, 0.0]]), 9)
    >>> float(np.round(k.sum(), 12)), k[4].nonzero()[0].tolist()
    (1.0, [2, 3, 4, 5, 6])
    """
    q = np.asarray(traj, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or q.shape[0] < 2 or not np.all(np.isfinite(q)):
        raise BlurEstimateError(f"a trajectory must be finite (T >= 2, 2), got {q.shape}")
    if size < 3 or size % 2 == 0:
        raise BlurEstimateError(f"kernel size must be odd and >= 3, got {size}")
    seg = np.linalg.norm(np.diff(q, axis=0), axis=1)
    n = max(2, int(np.ceil(float(seg.sum()) * samples_per_px)) + 1)
    s = np.linspace(0.0, q.shape[0] - 1.0, n)
    i = np.minimum(s.astype(int), q.shape[0] - 2)
    f = (s - i)[:, None]
    pts = q[i] * (1 - f) + q[i + 1] * f
    pts = pts - 0.5 * (pts.min(axis=0) + pts.max(axis=0)) + size // 2
    if pts.min() < 0 or pts.max() > size - 1:
        raise BlurEstimateError(f"the trajectory does not fit a {size}x{size} kernel")
    k = np.zeros((size, size))
    x0 = np.minimum(np.floor(pts[:, 0]).astype(int), size - 2)
    y0 = np.minimum(np.floor(pts[:, 1]).astype(int), size - 2)
    fx, fy = pts[:, 0] - x0, pts[:, 1] - y0
    for dy, dx, wgt in (
        (0, 0, (1 - fx) * (1 - fy)),
        (0, 1, fx * (1 - fy)),
        (1, 0, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        np.add.at(k, (y0 + dy, x0 + dx), wgt)
    return k / k.sum()


def kernel_cepstrum(
    kernel: np.ndarray, radius: int, n: int, taper: float | None = DEFAULT_TAPER
) -> np.ndarray:
    """What :func:`tile_cepstrum` predicts for a tile blurred by ``kernel`` (square, sum > 0)
    on the FFT grid of side ``n`` (:func:`fft_size` of the tile): ``(2r+1, 2r+1)``."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] != k.shape[1] or not k.sum() > 0 or k.shape[0] > n:
        raise BlurEstimateError(f"a kernel must be square, of positive sum, <= {n}: {k.shape}")
    if not 2 <= radius <= n // 2 - 1:
        raise BlurEstimateError(f"radius {radius} does not fit an FFT grid of {n}")
    return _cepstrum(np.fft.fft2(k, s=(n, n)), radius, taper)


def annulus(radius: int, r_min: float) -> np.ndarray:
    """Boolean mask ``(2r+1, 2r+1)`` of the lags with ``r_min <= |lag| <= radius``."""
    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    r = np.hypot(x, y)
    return (r >= r_min) & (r <= radius)


def kernel_score(tmap: np.ndarray, kmap: np.ndarray, r_min: float = 6.0) -> float:
    """Normalised cross-correlation in ``[-1, 1]`` of a tile map and a kernel map over the
    annulus ``r_min <= |lag| <= radius`` (both maps of the same ``radius`` and FFT grid).

    >>> k = rasterize(np.array([[0.0, 0.0], [12.0, 5.0]]), 31)
    >>> m = kernel_cepstrum(k, 15, 64)
    >>> round(kernel_score(m, m), 6)
    1.0
    """
    a, b = np.asarray(tmap, float), np.asarray(kmap, float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] % 2 == 0:
        raise BlurEstimateError(f"maps must be equal odd squares, got {a.shape} and {b.shape}")
    m = annulus(a.shape[0] // 2, r_min)
    x, y = a[m] - a[m].mean(), b[m] - b[m].mean()
    den = float(np.sqrt(np.sum(x**2) * np.sum(y**2)))
    return float(np.sum(x * y) / den) if den > 0 else 0.0


def line_kernel(vector_px: tuple[float, float] | np.ndarray, size: int) -> np.ndarray:
    """Kernel ``(size, size)`` of a straight blur along ``vector_px = (dx, dy)`` (px)."""
    v = np.asarray(vector_px, dtype=float)
    return rasterize(np.stack([-0.5 * v, 0.5 * v]), size)


def estimate_blur_vector(
    tile: np.ndarray,
    radius: int = 32,
    r_min: float = 6.0,
    min_score: float = 0.25,
    min_margin: float = 0.1,
    angle_step_deg: float = 6.0,
    taper: float | None = DEFAULT_TAPER,
) -> BlurVector | None:
    """The straight-line blur vector of a gray tile ``(h, w)``, or ``None`` if undetermined.

    The line kernel whose :func:`kernel_cepstrum` best matches the tile's
    :func:`tile_cepstrum` (:func:`kernel_score`): a grid over direction (``angle_step_deg``)
    and length (``r_min`` to ``radius - 2`` px in steps of ``r_min / 2``), then a Nelder–Mead
    refinement of ``(dx, dy)``. A curved trajectory yields about its chord. Undetermined
    (``None``): no texture, or a best score below ``min_score`` (the tile does not look like any
    straight blur), or a ``margin`` below ``min_margin`` (the perpendicular line explains it
    about as well: no direction). Blurs shorter than ``r_min`` or longer than ``radius - 2``
    px are outside its range; the tile should be at least ``3 · radius`` px on a side.

    >>> rng = np.random.default_rng(0)
    >>> f = np.hypot(*np.meshgrid(np.fft.fftfreq(192), np.fft.fftfreq(192))) + 1 / 192
    >>> scene = np.fft.ifft2(np.fft.fft2(rng.standard_normal((192, 192))) / f).real
    >>> k = rasterize(np.array([[0.0, 0.0], [16.0, 9.0]]), 41)
    >>> est = estimate_blur_vector(cv2.filter2D(scene, -1, k)[32:-32, 32:-32], radius=30)
    >>> [round(abs(v)) for v in est.vector_px]
    [16, 9]
    >>> estimate_blur_vector(np.full((128, 128), 0.5)) is None
    True
    """
    from scipy.optimize import minimize

    tmap = tile_cepstrum(tile, radius, taper)
    if tmap is None:
        return None
    n = fft_size(np.shape(tile))
    size = 2 * radius + 1

    def score(v: np.ndarray) -> float:
        if not np.hypot(v[0], v[1]) <= radius - 2:
            return -1.0
        kmap = kernel_cepstrum(line_kernel(v, size), radius, n, taper)
        return kernel_score(tmap, kmap, r_min)

    best, best_v = -np.inf, np.zeros(2)
    for L in np.arange(r_min, radius - 2 + 1e-9, max(r_min / 2, 1.0)):
        for th in np.radians(np.arange(0.0, 180.0, angle_step_deg)):
            v = L * np.array([np.cos(th), np.sin(th)])
            sc = score(v)
            if sc > best:
                best, best_v = sc, v
    simplex = best_v + np.array([[0.0, 0.0], [1.5, 0.0], [0.0, 1.5]])
    res = minimize(
        lambda v: -score(v),
        best_v,
        method="Nelder-Mead",
        options={"xatol": 0.05, "fatol": 1e-5, "initial_simplex": simplex},
    )
    v, sc = (np.asarray(res.x, float), -float(res.fun)) if -res.fun > best else (best_v, best)
    margin = sc - score(np.array([-v[1], v[0]]))
    if sc < min_score or margin < min_margin:
        return None
    dx, dy = float(v[0]), float(v[1])
    if dy < 0 or (dy == 0 and dx < 0):
        dx, dy = -dx, -dy
    return BlurVector(
        vector_px=(dx, dy),
        length_px=float(np.hypot(dx, dy)),
        angle_deg=float(np.degrees(np.arctan2(dy, dx)) % 180.0),
        score=sc,
        margin=float(margin),
    )


def endpoint_difference(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Sign-free endpoint difference ``min(|m - p|, |m + p|)`` (px) of blur vectors ``(..., 2)``."""
    m, p = np.asarray(measured, float), np.asarray(predicted, float)
    return np.minimum(np.linalg.norm(m - p, axis=-1), np.linalg.norm(m + p, axis=-1))
