"""Render a blurred frame from a sharp reference image along the calibrated trajectories.

DESIGN's blur relation: ``B(x) = ∫₀¹ S(x + q_x(τ)) dτ`` where ``S`` is the scene at the reference
time ``t_ref`` and ``x + q_x(τ) = warp(x, t_r + τ·exposure -> t_ref)`` with ``t_r`` the start of
exposure of ``x``'s row (rolling shutter). Rotations come from
:meth:`blurtrack.geometry.blur_model.BlurModel.rotations` (the one model), so the blur, the heat
maps of
:meth:`~blurtrack.geometry.blur_model.BlurModel.heat_maps` and the calibration agree by
construction.

The integral is a midpoint rule ``B ≈ Σ_k w_k S(x + q_x(τ_k))`` whose cells are chosen so that
consecutive samples of every pixel move at most ``max_step_px`` (0.5 px: the source paper's
"n_j = trajectory length" rule made sub-pixel): cells of equal *motion* (not of equal time),
found from the peak trajectory motion on a planning grid sampled finely in τ
(:func:`plan_samples`).

Two exact warping paths (see docs/synthesis.md):

* global shutter without distortion: each sample is one homography ``K Rᵀ K⁻¹`` applied with
  ``cv2.warpPerspective``;
* rolling shutter or lens distortion: each sample's source coordinates are computed exactly on
  a coarse node grid (``grid_px`` apart) and interpolated bilinearly to every pixel with
  ``cv2.resize`` (the maps are smooth: second derivatives of a rotation warp are ~1e-4 px/px²,
  so the interpolation error is ~1e-3 px, measured in the tests), then ``cv2.remap``.

Borders: samples that fall outside the sharp image read it reflected (``reflect``,
``cv2.BORDER_REFLECT_101``) or as black (``constant``); :class:`RenderResult` carries a
validity mask of the pixels whose every sample stayed inside the image.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.kernels import project_c, unproject_c

BORDERS = {"reflect": cv2.BORDER_REFLECT_101, "constant": cv2.BORDER_CONSTANT}
#: Samples processed together in the remap path (bounds memory at ~10 MB of node maps).
_TAU_CHUNK = 64
#: Pixels per band of rows processed through all samples of a chunk (fits the CPU cache).
_BAND_PIXELS = 131072


@dataclass(frozen=True)
class RenderSettings:
    """How finely the blur integral is sampled and how warps are evaluated.

    Args:
        max_step_px: largest motion between consecutive samples (px).
        grid_px: largest node spacing of the exact coarse maps in the remap path (px).
        map_tol_px: target bilinear-interpolation error of those maps; the spacing shrinks
            below ``grid_px`` when needed (error ≈ θ s² / (4 f) for a rotation θ, focal f).
        border: ``reflect`` or ``constant`` (see module docstring).
        max_samples: refuse blur that would need more samples than this.
        plan_tau, plan_grid: τ samples and grid nodes per axis of the step planning.
        adaptive: place samples by motion rather than evenly in τ (see :func:`plan_samples`).
    """

    max_step_px: float = 0.5
    grid_px: int = 16
    map_tol_px: float = 0.002
    border: str = "reflect"
    max_samples: int = 4000
    plan_tau: int = 129
    plan_grid: int = 9
    adaptive: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_step_px) and 0 < self.max_step_px <= 4):
            raise SynthesisError(f"max_step_px must be in (0, 4], got {self.max_step_px}")
        if not 2 <= int(self.grid_px) <= 256:
            raise SynthesisError(f"grid_px must be in [2, 256], got {self.grid_px}")
        if not (math.isfinite(self.map_tol_px) and self.map_tol_px > 0):
            raise SynthesisError(f"map_tol_px must be positive, got {self.map_tol_px}")
        if self.border not in BORDERS:
            raise SynthesisError(f"border must be one of {sorted(BORDERS)}, got {self.border!r}")
        if int(self.max_samples) < 2 or int(self.plan_tau) < 3 or int(self.plan_grid) < 2:
            raise SynthesisError("max_samples >= 2, plan_tau >= 3 and plan_grid >= 2 required")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class RenderResult:
    """A rendered blur: ``blur`` float32 like the input, ``valid (H, W)`` bool, the sample
    parameters ``tau (n,)`` and their weights, the largest planned step between samples (px)
    and the path used."""

    blur: np.ndarray
    valid: np.ndarray
    tau: np.ndarray
    max_step_px: float
    path: str
    weights: np.ndarray | None = None


def source_positions(
    model: BlurModel,
    frame_t_s: float,
    exposure_s: float,
    t_ref_s: float,
    u: np.ndarray,
    v: np.ndarray,
    tau: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """``x + q_x(τ)`` for the node grid ``u (gw,) × v (gh,)``: ``(mapx, mapy)`` each
    ``(T, gh, gw)`` in pixels of the sharp reference image (camera clock, seconds)."""
    cam = model.camera
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    tau = np.asarray(tau, float)
    t = cam.row_start_s(frame_t_s, v)[None, :] + exposure_s * tau[:, None]  # (T, gh)
    R = model.rotations(t.reshape(-1), np.full(t.size, float(t_ref_s)))
    R = R.reshape(tau.size, v.size, 3, 3)
    rx, ry, _ = unproject_c(u[None, :], v[:, None], cam.intrinsics, cam.dist)
    rx = np.broadcast_to(rx, (v.size, u.size))
    ry = np.broadcast_to(ry, (v.size, u.size))
    # warp uses R^T: X_a = sum_b R[b, a] ray_b with ray = (rx, ry, 1).
    X = R[:, :, None, 0, 0] * rx + R[:, :, None, 1, 0] * ry + R[:, :, None, 2, 0]
    Y = R[:, :, None, 0, 1] * rx + R[:, :, None, 1, 1] * ry + R[:, :, None, 2, 1]
    Z = R[:, :, None, 0, 2] * rx + R[:, :, None, 1, 2] * ry + R[:, :, None, 2, 2]
    return project_c(X, Y, Z, cam.intrinsics, cam.dist)


@dataclass(frozen=True)
class SamplePlan:
    """Sample parameters ``tau (n,)`` with weights ``(n,)`` summing to 1, the largest planned
    step between consecutive samples (px) and the largest ``|q|`` (px)."""

    tau: np.ndarray
    weights: np.ndarray
    step_px: float
    reach_px: float


def plan_samples(
    model: BlurModel, frame_t_s: float, exposure_s: float, t_ref_s: float, settings: RenderSettings
) -> SamplePlan:
    """Samples of the blur integral such that consecutive ones move at most ``max_step_px``.

    The peak (over a planning grid) per-interval motion, accumulated over τ, is a "motion
    clock" ``A(τ)``; ``n = ceil(A(1) / max_step)`` cells of equal motion are laid out on it and
    each sample sits at its cell's motion midpoint with the cell's τ width as weight (with
    ``adaptive=False``: equal cells in τ sized by the peak speed, the plain midpoint rule).
    Adaptive cells need fewer samples when the camera speeds up and slows down in one exposure.
    """
    W, H = model.camera.resolution
    u = np.linspace(0.0, W - 1.0, settings.plan_grid)
    v = np.linspace(0.0, H - 1.0, settings.plan_grid)
    fine = np.linspace(0.0, 1.0, settings.plan_tau)
    mx, my = source_positions(model, frame_t_s, exposure_s, t_ref_s, u, v, fine)
    seg = np.max(np.hypot(np.diff(mx, axis=0), np.diff(my, axis=0)), axis=(1, 2))
    reach = float(np.max(np.hypot(mx - u[None, None, :], my - v[None, :, None])))
    if not settings.adaptive:
        seg = np.full(seg.shape, float(seg.max()))
    clock = np.concatenate([[0.0], np.cumsum(seg)])
    total = float(clock[-1])
    n = max(2, math.ceil(total / settings.max_step_px - 1e-9))
    if n > settings.max_samples:
        raise SynthesisError(
            f"blur moves up to {total:.0f} px per exposure and would need {n} "
            f"samples (limit {settings.max_samples})"
        )
    if total < 1e-9:  # no motion: any cells will do
        edges = np.linspace(0.0, 1.0, n + 1)
        return SamplePlan((edges[:-1] + edges[1:]) / 2, np.diff(edges), 0.0, reach)
    # A tiny floor keeps the clock strictly increasing where some interval did not move.
    clock += np.linspace(0.0, 1e-9 * total, clock.size)
    marks = np.linspace(0.0, float(clock[-1]), 2 * n + 1)
    tau_marks = np.interp(marks, clock, fine)
    return SamplePlan(tau_marks[1::2], np.diff(tau_marks[0::2]), total / n, reach)


def node_spacing(model: BlurModel, reach_px: float, settings: RenderSettings) -> int:
    """Coarse-map node spacing meeting ``map_tol_px``: ``s = 2 f sqrt(tol / reach)``."""
    f = min(model.camera.intrinsics[:2])
    s = 2 * f * math.sqrt(settings.map_tol_px / max(reach_px, 1.0))
    return int(min(settings.grid_px, max(4, math.floor(s))))


@dataclass(frozen=True)
class NodeGrid:
    """Coarse nodes ``spacing`` px apart laid out so that ``cv2.resize`` (INTER_LINEAR,
    pixel-centre convention) of a ``(gh, gw)`` node array to the ``(gh·s, gw·s)`` canvas
    interpolates exactly between nodes; the image is the canvas from ``(p, p)`` on, and every
    image pixel lies inside the node hull (no clamped extrapolation). The integer spacing lets
    any band of rows be upsampled on its own, with the same values (:meth:`upsample_rows`)."""

    u: np.ndarray
    v: np.ndarray
    pad: int
    width: int
    height: int
    spacing: int = 1

    @classmethod
    def build(cls, width: int, height: int, grid_px: int) -> NodeGrid:
        s = int(grid_px)
        p = math.ceil(s / 2)

        def axis(n: int) -> np.ndarray:
            count = max(2, math.ceil((n + 2 * p) / s))
            return (np.arange(count) + 0.5) * s - 0.5 - p

        return cls(axis(width), axis(height), p, width, height, s)

    def upsample(self, nodes: np.ndarray) -> np.ndarray:
        """Node values ``(gh, gw[, C])`` float32 to every pixel ``(H, W[, C])`` (a view)."""
        return self.upsample_rows(nodes, 0, self.height)

    def upsample_rows(
        self, nodes: np.ndarray, y0: int, rows: int, canvas: np.ndarray | None = None
    ) -> np.ndarray:
        """Rows ``y0 .. y0 + rows - 1`` of :meth:`upsample` (a view; ``canvas`` is an optional
        reusable contiguous float32 buffer of at least ``(rows + 3s)·gw·s·C`` values).

        Only the node rows around the band are resized: a sub-array starting at node row
        ``ja`` maps canvas row ``c`` to node coordinate ``(c + 0.5)/s - 0.5 - ja``, exactly
        the full array's minus ``ja``, and clamps only where the full array clamps too.
        """
        s, p = self.spacing, self.pad
        c0, c1 = y0 + p, y0 + p + rows - 1  # first and last canvas rows
        ja = max(0, math.floor((c0 + 0.5) / s - 0.5))
        jb = min(self.v.size, math.floor((c1 + 0.5) / s - 0.5) + 2)
        part = np.ascontiguousarray(nodes[ja:jb], np.float32)
        size = (self.u.size * s, (jb - ja) * s)
        dst = None
        if canvas is not None:
            shape = (size[1], size[0], *part.shape[2:])
            dst = canvas.reshape(-1)[: math.prod(shape)].reshape(shape)
        up = cv2.resize(part, size, dst=dst, interpolation=cv2.INTER_LINEAR)
        return up[c0 - ja * s : c1 + 1 - ja * s, p : p + self.width]


def four_channels(img: np.ndarray) -> np.ndarray:
    """A 3-channel float32 image padded to 4 channels (the 4th is 1.0); others unchanged.

    OpenCV's ``remap`` and ``warpPerspective`` have vectorised float32 kernels for 1 and 4
    channels but not for 3: on a 4-channel copy they give bit-identical colour channels in
    about half the time (2.6 ms instead of 5.1 ms per 1280x720 warp on one core), which more
    than pays for the extra channel in the accumulation. Callers drop the 4th channel at the
    end (``cv2.COLOR_BGRA2BGR``).
    """
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    return img


def render_blur(
    sharp: np.ndarray,
    model: BlurModel,
    frame_t_s: float,
    exposure_s: float,
    t_ref_s: float | None = None,
    settings: RenderSettings | None = None,
) -> RenderResult:
    """Blur ``sharp`` (float32 ``(H, W)`` or ``(H, W, C)``, C <= 4, the scene at ``t_ref``; linear
    light for physically right averaging) over the frame exposed from ``frame_t_s`` (top row,
    camera clock) for ``exposure_s``. ``t_ref`` defaults to the model's mid-exposure time."""
    st = settings or RenderSettings()
    cam = model.camera
    W, H = cam.resolution
    img = np.asarray(sharp)
    if img.dtype != np.float32 or img.shape[:2] != (H, W) or img.ndim not in (2, 3):
        raise SynthesisError(
            f"sharp image must be float32 {H}x{W}[xC] to match the camera, "
            f"got {img.dtype} {img.shape}"
        )
    t_ref = (
        model.default_reference_time(frame_t_s, exposure_s) if t_ref_s is None else float(t_ref_s)
    )
    plan = plan_samples(model, frame_t_s, exposure_s, t_ref, st)
    tau, wts = plan.tau, plan.weights.astype(np.float32)
    n = tau.size
    border = BORDERS[st.border]
    work = four_channels(img)
    acc: np.ndarray = np.zeros(work.shape, np.float32)
    grid = NodeGrid.build(W, H, node_spacing(model, plan.reach_px, st))
    margin = np.full((grid.v.size, grid.u.size), np.inf)
    homography = cam.readout_s == 0 and not cam.dist
    # Whole node cells per band: each band then resizes only one node row more than it uses.
    band = grid.spacing * max(1, _BAND_PIXELS // (W * grid.spacing))
    bands = [(y0, min(band, H - y0)) for y0 in range(0, H, band)]
    warped = np.empty((band, *work.shape[1:]), np.float32)  # reused output of every warp
    canvas = np.empty(
        (band + 3 * grid.spacing) * grid.u.size * grid.spacing * 2, np.float32
    )  # reused per-pixel coordinate map of a band
    if homography:
        R = model.rotations(frame_t_s + exposure_s * tau, np.full(n, t_ref))
        K = cam.K
        Hs = K @ np.transpose(R, (0, 2, 1)) @ np.linalg.inv(K)
    for k0 in range(0, n, _TAU_CHUNK):
        mx, my = source_positions(
            model, frame_t_s, exposure_s, t_ref, grid.u, grid.v, tau[k0 : k0 + _TAU_CHUNK]
        )
        inside = np.minimum(np.minimum(mx, W - 1.0 - mx), np.minimum(my, H - 1.0 - my))
        margin = np.minimum(margin, inside.min(axis=0))
        # Absolute coordinates: the identity is linear, so bilinear upsampling keeps it exact.
        maps = None if homography else np.stack([mx, my], axis=-1).astype(np.float32)
        chunk = wts[k0 : k0 + _TAU_CHUNK]
        # Band by band, every sample: the band's accumulator, warp output and map stay in the
        # CPU cache (about 1.4x faster than whole frames, which are memory-bound).
        for y0, rows in bands:
            out = warped[:rows]
            dst = acc[y0 : y0 + rows]
            shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
            for k, wk in enumerate(chunk):
                if homography:
                    cv2.warpPerspective(
                        work,
                        Hs[k0 + k] @ shift,
                        (W, rows),
                        dst=out,
                        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                        borderMode=border,
                    )
                else:
                    assert maps is not None  # built whenever not homography
                    m = grid.upsample_rows(maps[k], y0, rows, canvas)
                    cv2.remap(work, m, None, cv2.INTER_LINEAR, dst=out, borderMode=border)  # type: ignore[call-overload]  # cv2 stubs: map2 may be None (2-channel map1)
                cv2.scaleAdd(out, float(wk), dst, dst=dst)
    if work is not img:
        acc = np.asarray(cv2.cvtColor(acc, cv2.COLOR_BGRA2BGR))
    valid = grid.upsample(margin) >= 0
    return RenderResult(
        acc,
        np.ascontiguousarray(valid),
        tau,
        plan.step_px,
        "homography" if homography else "remap",
        plan.weights,
    )
