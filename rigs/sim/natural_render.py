"""The natural-scene renderer's inner loop: many rolling-shutter sub-views summed in one pass.

A sub-view ``k`` of row ``r`` looks along ``w = u · A + B`` (``u`` the column, ``A``, ``B``
per ``(k, r)``) and samples the texture at ``c + s_t · (w_x, w_y) / w_z · f + o`` (``f``,
``o``: the forward-motion zoom and shift of a plane at finite depth, 1 and 0 for the far
plane). :func:`row_coefficients` folds ``f``, ``o`` and ``c`` into per-row coefficient pairs
(:class:`ViewGeometry`) and :func:`accumulate` evaluates the maps in float32 for bands of a
few rows and all sub-views at once (rank-2 matrix products; the working set stays in cache,
no full-frame temporaries), samples them with one ``cv2.remap`` per band and sums the
sub-views in their order. The texture is mirror-padded by one period of
``BORDER_REFLECT_101`` (:func:`pad_texture`) so that the sampler sees the same mirrored scene
with cheaper border handling. :func:`reference_view` is the one-sub-view-at-a-time
formulation it replaces (kept for tests and convergence studies); the two differ by float32
rounding of the texel coordinates (~1e-4 texel).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Target size (bytes) of one band's float32 map: a few hundred kB stays in L2.
BAND_BYTES = 384 * 1024


@dataclass(frozen=True)
class ViewGeometry:
    """Per-(sub-view, row) float32 coefficients ``(n, H, 2)`` of the texture maps.

    Texel ``x = (qx · [u, 1]) · s_t / (qz · [u, 1])`` and likewise ``y`` with ``qy``: ``qz`` is
    the ray's ``w_z = u · a_z + b_z``, and ``qx`` folds the forward-motion zoom
    ``1 − c_z / depth``, the camera centre's texel shift and the texture centre into the
    ray's ``w_x`` (``qx = zoom · (a_x, b_x) + (o_x + c_t) / s_t · (a_z, b_z)``), so that a
    map costs two rank-2 products and two element-wise operations.
    """

    qx: np.ndarray
    qy: np.ndarray
    qz: np.ndarray


def pad_texture(texture: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """``texture`` with a ``BORDER_REFLECT_101`` margin of one period's half (``W − 1``,
    ``H − 1``) on every side, and that margin ``(px, py)``.

    Reflect-101 is periodic with period ``2 (W − 1)``, so sampling the padded texture with the
    same border mode gives the original's mirrored scene at every coordinate.
    """
    h, w = texture.shape
    px, py = w - 1, h - 1
    padded = cv2.copyMakeBorder(texture, py, py, px, px, cv2.BORDER_REFLECT_101)
    return np.ascontiguousarray(padded, np.float32), (px, py)


def row_coefficients(
    R: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    texel_scale: float,
    centre: tuple[float, float],
    c: np.ndarray | None = None,
    depth_m: float | None = None,
) -> ViewGeometry:
    """Map coefficients for orientations ``R (n, H, 3, 3)`` (and camera centres ``c (n, H, 3)``
    with a plane at ``depth_m``), row ``r`` of sub-view ``k`` at ``R[k, r]``; ``centre`` the
    texture centre in the sampled (padded) texture's pixels."""
    fx, fy, cx, cy = intrinsics
    v = (np.arange(R.shape[1]) - cy) / fy
    a = R[..., :, 0] / fx  # (n, H, 3): w = u a + b
    b = R[..., :, 0] * (-cx / fx) + R[..., :, 1] * v[:, None] + R[..., :, 2]
    zoom: np.ndarray | float = 1.0
    shift = np.zeros((*a.shape[:2], 2))
    if depth_m is not None and c is not None:
        zoom = (1 - c[..., 2] / depth_m)[..., None]
        shift = c[..., :2] * (texel_scale / depth_m)
    k = (shift + np.asarray(centre, float)) / texel_scale  # (n, H, 2)

    def q(i: int) -> np.ndarray:
        lin = zoom * np.stack([a[..., i], b[..., i]], axis=-1)
        return (lin + k[..., i : i + 1] * np.stack([a[..., 2], b[..., 2]], axis=-1)).astype(
            np.float32
        )

    qz = np.stack([a[..., 2], b[..., 2]], axis=-1).astype(np.float32)
    return ViewGeometry(q(0), q(1), qz)


def accumulate(padded: np.ndarray, g: ViewGeometry, width: int, texel_scale: float) -> np.ndarray:
    """The sum over sub-views of the sampled texture, ``(H, W)`` float32 (see the module text);
    ``padded`` from :func:`pad_texture`."""
    n, H = g.qz.shape[:2]
    W = int(width)
    U = np.stack([np.arange(W, dtype=np.float32), np.ones(W, np.float32)])
    ts = np.float32(texel_scale)
    rows = max(1, min(H, BAND_BYTES // (4 * n * W)))
    s = np.empty((n * rows, W), np.float32)
    mx = np.empty_like(s)
    my = np.empty_like(s)
    val = np.empty_like(s)
    acc = np.empty((H, W), np.float32)
    for r0 in range(0, H, rows):
        r1 = min(H, r0 + rows)
        m = n * (r1 - r0)  # band rows in (sub-view, row) order
        d, x, y, o = s[:m], mx[:m], my[:m], val[:m]
        np.matmul(g.qz[:, r0:r1].reshape(m, 2), U, out=d)
        np.divide(ts, d, out=d)
        np.matmul(g.qx[:, r0:r1].reshape(m, 2), U, out=x)
        x *= d
        np.matmul(g.qy[:, r0:r1].reshape(m, 2), U, out=y)
        y *= d
        cv2.remap(
            padded, x, y, dst=o, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101
        )
        np.add.reduce(o.reshape(n, r1 - r0, W), axis=0, out=acc[r0:r1])
    return acc


def reference_view(
    texture: np.ndarray,
    R_rows: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    width: int,
    texel_scale: float,
    centre: tuple[float, float],
    c_rows: np.ndarray | None = None,
    depth_m: float | None = None,
) -> np.ndarray:
    """One sharp sub-view ``(H, W)`` for per-row orientations ``R_rows (H, 3, 3)``: the
    straightforward formulation (full-frame maps of the unpadded texture), for tests."""
    fx, fy, cx, cy = intrinsics
    H = R_rows.shape[0]
    v = (np.arange(H) - cy) / fy
    A = (R_rows[:, :, 0] / fx).astype(np.float32)
    B = (R_rows[:, :, 0] * (-cx / fx) + R_rows[:, :, 1] * v[:, None] + R_rows[:, :, 2]).astype(
        np.float32
    )
    u = np.arange(width, dtype=np.float32)[None, :]
    s = np.float32(texel_scale) / (A[:, 2:3] * u + B[:, 2:3])
    ox: np.ndarray | np.float32 = np.float32(0.0)
    oy: np.ndarray | np.float32 = np.float32(0.0)
    if depth_m is not None and c_rows is not None:
        c = c_rows.astype(np.float32)
        s = s * (1 - c[:, 2:3] / np.float32(depth_m))
        ox = c[:, 0:1] * np.float32(texel_scale / depth_m)
        oy = c[:, 1:2] * np.float32(texel_scale / depth_m)
    mx = (A[:, 0:1] * u + B[:, 0:1]) * s + ox + np.float32(centre[0])
    my = (A[:, 1:2] * u + B[:, 1:2]) * s + oy + np.float32(centre[1])
    return np.asarray(
        cv2.remap(
            texture, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101
        )
    )
