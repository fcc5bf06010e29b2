"""Equal-blur refinement of feature tracks: each frame re-blurred by the other's motion blur.

Lucas–Kanade between two differently blurred frames does not find where a scene point moved:
the patch of frame ``a`` is the sharp scene convolved with ``a``'s blur kernel ``k_a``, the
patch of frame ``b`` with ``k_b``, and the translation that best maps one onto the other
depends on both kernels and on the texture under the window (a corner at the end of a streak
is pulled along it). Convolving each patch with the *other* frame's kernel gives both the
same blur ``k_a * k_b`` (convolution commutes), so the patches differ by the scene point's
displacement alone::

    J_a = I_a * k_b = S * k_a * k_b,    J_b = I_b * k_a = S(· − s) * k_a * k_b = J_a(· − s)

and Lucas–Kanade on ``(J_a, J_b)`` measures ``s``. With kernels written as the point's image
positions over its exposure *relative to its mid-exposure position* (``o_k``, so that
``I(x) = mean_k S(x − o_k)`` with ``S`` the scene at mid-exposure), ``s`` is the displacement
between the two mid-exposure positions: the refined ``(pts_a, pts_b)`` are mid-exposure
positions, with no blur-centroid correction to apply.

The kernels come from outside (the gyro-driven blur model, :mod:`calib.natural.pipeline`); this
module only filters images. A kernel is locally constant: it is rendered once per track and applied
to a small patch around each end (``cv2.getRectSubPix``, ``cv2.filter2D``), then a
single-level Lucas–Kanade refines ``pts_b`` from its first estimate.
"""

from __future__ import annotations

from functools import partial
from itertools import pairwise

import cv2
import numpy as np

from blurtrack.features.pairs import concurrently, usable_cores
from blurtrack.features.tracks import FeatureTrackError

#: Lucas–Kanade window (px) and how far (px) a refinement may move a point.
WINDOW_PX = 21
MARGIN_PX = 4
#: Longest kernel (px from its centre) the refinement accepts; longer tracks are dropped.
MAX_KERNEL_PX = 60
#: Fewest tracks per thread of :func:`refine_patches`.
MIN_CHUNK = 256


def kernel_stack(offsets: np.ndarray, radius: int) -> np.ndarray:
    """``(N, 2r+1, 2r+1)`` float32 kernels for :func:`cv2.filter2D` whose correlation with an
    image ``I`` gives ``J(x) = mean_k I(x − o_k)`` (``offsets (N, n, 2)`` px, bilinear splats;
    samples beyond the radius are dropped)."""
    o = np.asarray(offsets, float)
    n = o.shape[0]
    side = 2 * radius + 1
    # filter2D: J(x) = Σ_u K(u) I(x + u − r); I(x − o) needs weight at u = r − o.
    u = radius - o.reshape(n, -1, 2)
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    idx, wts = [], []
    base = np.arange(n)[:, None] * side * side
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        w = (f[..., 0] if dx else 1 - f[..., 0]) * (f[..., 1] if dy else 1 - f[..., 1])
        xs, ys = i0[..., 0] + dx, i0[..., 1] + dy
        ok = (xs >= 0) & (xs < side) & (ys >= 0) & (ys < side)
        idx.append((base + ys * side + xs)[ok])
        wts.append(w[ok])
    k = np.bincount(np.concatenate(idx), np.concatenate(wts), minlength=n * side * side)
    k = k.reshape(n, side, side)
    return (k / np.maximum(k.sum(axis=(1, 2), keepdims=True), 1e-12)).astype(np.float32)


def _patch(img: np.ndarray, centre: np.ndarray, half: int) -> np.ndarray:
    size = 2 * half + 1
    return cv2.getRectSubPix(img, (size, size), (float(centre[0]), float(centre[1])))


def refine_equal_blur(
    img_a: np.ndarray,
    img_b: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    offsets_a: np.ndarray,
    offsets_b: np.ndarray,
    window_px: int = WINDOW_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """``pts_b`` refined so that frame ``a`` blurred by ``offsets_b`` around ``pts_a`` matches
    frame ``b`` blurred by ``offsets_a`` around it (see the module docstring).

    ``img_a``, ``img_b``: frames as float32 or 8-bit gray; ``pts_a``, ``pts_b``: ``(N, 2)``
    matched pixels (``pts_b`` a first estimate within :data:`MARGIN_PX`); ``offsets_a``,
    ``offsets_b``: ``(N, n, 2)`` each point's image positions over its exposure relative to
    its mid-exposure position, in its own frame. Returns the refined ``pts_b`` ``(N, 2)`` and
    whether each refinement converged inside the margin ``(N,)`` (others keep ``pts_b``).
    """
    patches = equal_blur_patches(img_a, img_b, pts_a, pts_b, offsets_a, offsets_b, window_px)
    return refine_patches(pts_b, *patches)


def equal_blur_patches(
    img_a: np.ndarray,
    img_b: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    offsets_a: np.ndarray,
    offsets_b: np.ndarray,
    window_px: int = WINDOW_PX,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The equally blurred patches :func:`refine_equal_blur` matches (arguments as there):
    templates ``(N, w+2, w+2)`` around ``pts_a``, targets ``(N, P, P)`` around ``pts_b`` and
    which tracks have kernels short enough to refine ``(N,)``. Patches of several frame pairs
    concatenated go to one :func:`refine_patches` (the same result as pair by pair)."""
    pa, pb = np.asarray(pts_a, float), np.asarray(pts_b, float)
    oa, ob = np.asarray(offsets_a, float), np.asarray(offsets_b, float)
    n = len(pa)
    if pb.shape != (n, 2) or oa.shape[0] != n or ob.shape[0] != n or oa.shape[2:] != (2,):
        raise FeatureTrackError("equal-blur refinement: points and kernels differ in shape")
    if window_px < 5 or window_px % 2 == 0:
        raise FeatureTrackError(f"window_px must be odd and >= 5, got {window_px}")
    h = window_px // 2
    half = h + MARGIN_PX + 1
    ta = np.zeros((n, 2 * h + 3, 2 * h + 3), np.float32)
    jb = np.zeros((n, 2 * half + 1, 2 * half + 1), np.float32)
    if n == 0:
        return ta, jb, np.zeros(0, bool)
    A = np.asarray(img_a, np.float32)
    B = np.asarray(img_b, np.float32)
    ext = np.maximum(np.abs(oa).max(axis=(1, 2)), np.abs(ob).max(axis=(1, 2)))
    usable = ext <= MAX_KERNEL_PX
    rad = np.ceil(np.where(usable, ext, 0)).astype(np.int64) + 1
    R = int(rad.max())
    ka, kb = kernel_stack(oa, R), kernel_stack(ob, R)
    for i in np.flatnonzero(usable):
        r = int(rad[i])
        c = slice(R - r, R + r + 1)
        a = cv2.filter2D(_patch(A, pa[i], h + 1 + r), -1, kb[i, c, c])
        b = cv2.filter2D(_patch(B, pb[i], half + r), -1, ka[i, c, c])
        ta[i] = a[r:-r, r:-r]
        jb[i] = b[r:-r, r:-r]
    return ta, jb, usable


def refine_patches(
    pts_b: np.ndarray,
    template: np.ndarray,
    target: np.ndarray,
    usable: np.ndarray,
    workers: int | None = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`refine_equal_blur`'s result from :func:`equal_blur_patches`'s: Lucas–Kanade
    on the patches, each point moved by its converged translation inside the margin.

    ``workers`` threads (``None``: every usable core) share the tracks in chunks of at least
    :data:`MIN_CHUNK` (numpy's array work runs without the GIL; each track's translation
    depends on its own patches only, so the result does not depend on the split)."""
    pb = np.asarray(pts_b, float)
    out, ok = pb.copy(), np.zeros(len(pb), bool)
    if len(pb) == 0:
        return out, ok
    k = max(1, min(len(pb) // MIN_CHUNK, usable_cores() if workers is None else workers))
    cuts = np.linspace(0, len(pb), k + 1).astype(int)
    parts = concurrently(
        [partial(lucas_kanade, template[a:b], target[a:b]) for a, b in pairwise(cuts)]
    )
    d = np.concatenate([p[0] for p in parts])
    conv = np.concatenate([p[1] for p in parts])
    good = usable & conv & np.all(np.abs(d) < MARGIN_PX, axis=1)
    out[good] = pb[good] + d[good]
    return out, good


def _bilinear(img: np.ndarray, rows: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``img (N, P, P)``'s patches ``rows (K,)`` sampled at ``x, y (K, M)`` (inside by
    construction). Indexing by row instead of sampling ``img[rows]`` saves copying the active
    patches in every Lucas–Kanade iteration; the values are the same."""
    n, P, _ = img.shape
    x = np.clip(x, 0, P - 1.001).astype(np.float32)
    y = np.clip(y, 0, P - 1.001).astype(np.float32)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    flat = img.reshape(n, -1)
    base = y0 * P + x0
    r = rows[:, None]

    def at(o: np.ndarray) -> np.ndarray:
        return flat[r, o]

    top = at(base) * (1 - fx) + at(base + 1) * fx
    bot = at(base + P) * (1 - fx) + at(base + P + 1) * fx
    return top * (1 - fy) + bot * fy


def lucas_kanade(
    template: np.ndarray, target: np.ndarray, iterations: int = 20, tol: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Translations ``(N, 2)`` (px) of ``template (N, w+2, w+2)``'s inner ``w × w`` window in
    ``target (N, P, P)`` relative to both patches' centres (inverse-compositional
    Lucas–Kanade, float, vectorised over the tracks) and whether each converged ``(N,)``."""
    T = np.asarray(template, np.float32)
    n, q, _ = T.shape
    w = q - 2
    gx = (T[:, 1:-1, 2:] - T[:, 1:-1, :-2]) / 2
    gy = (T[:, 2:, 1:-1] - T[:, :-2, 1:-1]) / 2
    t = T[:, 1:-1, 1:-1].reshape(n, -1)
    gx, gy = gx.reshape(n, -1), gy.reshape(n, -1)
    Hm = np.stack(
        [np.sum(gx * gx, 1), np.sum(gx * gy, 1), np.sum(gx * gy, 1), np.sum(gy * gy, 1)], 1
    ).reshape(n, 2, 2)
    det = Hm[:, 0, 0] * Hm[:, 1, 1] - Hm[:, 0, 1] ** 2
    well = det > 1e-9 * np.maximum(Hm[:, 0, 0] + Hm[:, 1, 1], 1e-12) ** 2
    Hi = np.linalg.inv(np.where(well[:, None, None], Hm, np.eye(2)))
    P = target.shape[1]
    c = (P - 1) / 2
    g = np.arange(w) - (w - 1) / 2
    ux = np.tile(g, w)[None, :]
    uy = np.repeat(g, w)[None, :]
    tg = np.asarray(target, np.float32)
    d = np.zeros((n, 2))
    conv = np.zeros(n, bool)
    for _ in range(iterations):
        act = ~conv
        if not np.any(act):
            break
        s = _bilinear(tg, np.flatnonzero(act), c + d[act, 0:1] + ux, c + d[act, 1:2] + uy)
        e = s - t[act]
        b = np.stack([np.sum(gx[act] * e, 1), np.sum(gy[act] * e, 1)], 1)
        step = np.einsum("nij,nj->ni", Hi[act], b)
        d[act] -= step
        conv[np.flatnonzero(act)[np.max(np.abs(step), 1) < tol]] = True
    return d, conv & well
