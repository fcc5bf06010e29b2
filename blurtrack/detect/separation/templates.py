"""Templates for :mod:`blurtrack.detect.separation.separate`: a clean streak's pixels of the
smoothed (and raw) frame, its support and halo, mapped onto another place of the frame by a rotation
and scaling, and placements of them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from blurtrack.detect.lines.segment import Components

#: Width (px) of the ring around a template's support that must be dark where it is placed
#: (how much of it may be lit: ``separation.halo_max``). Fixed: templates are padded by it
#: and the ring's disk is built once, here.
HALO_PX = 3
_HALO_DISK = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * HALO_PX + 1, 2 * HALO_PX + 1))


@dataclass(frozen=True)
class Template:
    box: tuple[int, int, int, int]  # x, y, w, h in the frame
    smooth: np.ndarray  # (h, w) float32, zero off the reference's component
    raw: np.ndarray  # the same of the unsmoothed signal
    support: np.ndarray  # (h, w) float32 0/1
    halo: np.ndarray  # (h, w) float32 0/1: a ring of HALO_PX around the support
    norm2: float
    points: np.ndarray  # the reference's centre line, frame coordinates
    area: int


@dataclass(frozen=True)
class Placement:
    tpl: Template
    shift: np.ndarray  # (2,) frame offset of the template (sub-pixel)
    amp: float
    comp: int


def finish(
    box: tuple[int, int, int, int],
    sm: np.ndarray,
    raw: np.ndarray | None,
    sup: np.ndarray,
    pts: np.ndarray,
) -> Template:
    """A template padded by :data:`HALO_PX` of zeros, with its halo (``raw`` None: zero)."""
    m = HALO_PX
    x, y, w, h = box

    def pad(a: np.ndarray) -> np.ndarray:
        out = np.zeros((a.shape[0] + 2 * m, a.shape[1] + 2 * m), np.float32)
        out[m:-m, m:-m] = a
        return out

    sm, sup = pad(sm), pad(sup)
    raw = np.zeros_like(sm) if raw is None else pad(raw)
    halo = cv2.dilate(sup, _HALO_DISK) - sup
    return Template(
        (x - m, y - m, w + 2 * m, h + 2 * m),
        sm,
        raw,
        sup,
        halo,
        cv2.norm(sm, cv2.NORM_L2SQR),
        pts,
        cv2.countNonZero(sup),
    )


def template(
    smooth: np.ndarray, signal: np.ndarray, comps: Components, c: int, pts: np.ndarray
) -> Template:
    x, y, w, h = (int(v) for v in comps.boxes[c])
    sup = comps.labels[y : y + h, x : x + w] == comps.ids[c]
    t = np.where(sup, smooth[y : y + h, x : x + w], 0.0)
    raw = np.where(sup, signal[y : y + h, x : x + w], 0.0)
    return finish((x, y, w, h), t, raw, sup, pts)


def similar(t: Template, z: complex, pivot: np.ndarray) -> Template:
    """``t`` rotated and scaled by the complex factor ``z`` about ``pivot`` (frame px)."""
    M = np.array([[z.real, -z.imag], [z.imag, z.real]])
    x, y, w, h = t.box
    corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], float)
    moved = (corners - pivot) @ M.T + pivot
    nx, ny = np.floor(moved.min(axis=0)).astype(int) - 1
    nw, nh = (np.ceil(moved.max(axis=0)).astype(int) + 2) - (nx, ny)
    A = np.hstack([M, (M @ (np.array([x, y], float) - pivot) + pivot - (nx, ny))[:, None]])

    def warp(img: np.ndarray) -> np.ndarray:
        return cv2.warpAffine(img, A, (int(nw), int(nh)), flags=cv2.INTER_LINEAR, borderValue=0.0)

    sup = (warp(t.support) > 0.5).astype(np.float32)
    sm, raw = warp(t.smooth) * sup, warp(t.raw) * sup
    pts = (t.points - pivot) @ M.T + pivot
    return finish((int(nx), int(ny), int(nw), int(nh)), sm, raw, sup, pts)


def warp(t: np.ndarray, dx: float, dy: float, w: int, h: int) -> np.ndarray:
    m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    return cv2.warpAffine(t, m, (w, h), flags=cv2.INTER_LINEAR, borderValue=0.0)


def inside_norm2(
    frame: tuple[int, int, int, int] | None,
    region: tuple[int, int, int, int],
    sm: np.ndarray,
) -> np.ndarray | None:
    """Per placement of the template image ``sm`` over ``region = (x0, y0, x1, y1)`` of an
    image padded beyond the frame (``frame = (fx0, fy0, fx1, fy1)``, the frame's pixels in the
    padded image), the squared norm of the template's part inside the frame, the shape of
    ``cv2.matchTemplate`` over the region (a rectangle of the template per placement: four
    look-ups of its integral image); None where every placement lies wholly inside (or
    ``frame`` is None): the norm is the whole template's."""
    if frame is None:
        return None
    fx0, fy0, fx1, fy1 = frame
    x0, y0, x1, y1 = region
    th, tw = sm.shape
    if x0 >= fx0 and y0 >= fy0 and x1 <= fx1 and y1 <= fy1:
        return None
    px = np.arange(x0, x1 - tw + 1)
    py = np.arange(y0, y1 - th + 1)
    c0, c1 = np.clip(fx0 - px, 0, tw), np.clip(fx1 - px, 0, tw)
    r0, r1 = np.clip(fy0 - py, 0, th), np.clip(fy1 - py, 0, th)
    sq = sm.astype(np.float64) ** 2
    S = np.zeros((th + 1, tw + 1))
    S[1:, 1:] = sq.cumsum(axis=0).cumsum(axis=1)
    n2 = S[np.ix_(r1, c1)] - S[np.ix_(r0, c1)] - S[np.ix_(r1, c0)] + S[np.ix_(r0, c0)]
    return np.asarray(np.maximum(n2, 0.0), np.float32)


class InsideNorms:
    """:func:`inside_norm2` over one padded image (``frame``), remembered per template image
    and region: the gyro pass pursues and refits the same templates over the same regions
    again (its sweeps; hard, 12 frames: 1 083 of 2 346 pursuits' and 3 022 of 6 675 refit
    steps' norms were repeats)."""

    def __init__(self, frame: tuple[int, int, int, int] | None) -> None:
        self.frame = frame
        # (id of the template image, region) -> (that image, its norms); the image is kept
        # so that its id names it as long as the entry lives.
        self._memo: dict[tuple[int, tuple[int, int, int, int]], tuple[np.ndarray, Any]] = {}

    def __call__(self, region: tuple[int, int, int, int], sm: np.ndarray) -> np.ndarray | None:
        """:func:`inside_norm2` ``(self.frame, region, sm)``."""
        key = (id(sm), region)
        hit = self._memo.get(key)
        if hit is None or hit[0] is not sm:
            hit = (sm, inside_norm2(self.frame, region, sm))
            self._memo[key] = hit
        return hit[1]
