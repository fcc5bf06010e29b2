"""Render a blurred frame from a sharp reference image along the calibrated trajectories.

DESIGN's blur relation: ``B(x) = ∫₀¹ S(x + q_x(τ)) dτ`` where ``S`` is the scene at the reference
time ``t_ref`` and ``x + q_x(τ) = warp(x, t_r + τ·exposure -> t_ref)`` with ``t_r`` the start of
exposure of ``x``'s row (rolling shutter). Rotations come from
:meth:`blurtrack.trajectory.BlurModel.rotations` (the one model), so the blur, the heat maps of
:meth:`~blurtrack.trajectory.BlurModel.heat_maps` and the calibration agree by construction.

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
from blurtrack.model import project_c, unproject_c
from blurtrack.trajectory import BlurModel

BORDERS = {"reflect": cv2.BORDER_REFLECT_101, "constant": cv2.BORDER_CONSTANT}
#: Samples processed together in the remap path (bounds memory at ~10 MB of node maps).
_TAU_CHUNK = 64


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


def source_positions(model: BlurModel, frame_t_s: float, exposure_s: float, t_ref_s: float,
                     u: np.ndarray, v: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, ...]:
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


def plan_samples(model: BlurModel, frame_t_s: float, exposure_s: float, t_ref_s: float,
                 settings: RenderSettings) -> SamplePlan:
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
        raise SynthesisError(f"blur moves up to {total:.0f} px per exposure and would need {n} "
                             f"samples (limit {settings.max_samples})")
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
    """Coarse nodes laid out so that ``cv2.resize`` (INTER_LINEAR, pixel-centre convention)
    of a ``(gh, gw)`` node array to ``(H + 2p, W + 2p)`` interpolates exactly between nodes;
    the image is the canvas cropped by ``p`` on every side, and every image pixel lies inside
    the node hull (no clamped extrapolation)."""

    u: np.ndarray
    v: np.ndarray
    pad: int
    width: int
    height: int

    @classmethod
    def build(cls, width: int, height: int, grid_px: int) -> NodeGrid:
        p = math.ceil(grid_px / 2)

        def axis(n: int) -> np.ndarray:
            count = max(2, math.ceil((n + 2 * p) / grid_px))
            s = (n + 2 * p) / count
            return (np.arange(count) + 0.5) * s - 0.5 - p

        return cls(axis(width), axis(height), p, width, height)

    def upsample(self, nodes: np.ndarray) -> np.ndarray:
        """Node values ``(gh, gw[, C])`` float32 to every pixel ``(H, W[, C])`` (a view)."""
        p = self.pad
        up = cv2.resize(np.ascontiguousarray(nodes, np.float32),
                        (self.width + 2 * p, self.height + 2 * p),
                        interpolation=cv2.INTER_LINEAR)
        return up[p:p + self.height, p:p + self.width]


def render_blur(sharp: np.ndarray, model: BlurModel, frame_t_s: float, exposure_s: float,
                t_ref_s: float | None = None,
                settings: RenderSettings | None = None) -> RenderResult:
    """Blur ``sharp`` (float32 ``(H, W)`` or ``(H, W, C)``, C <= 4, the scene at ``t_ref``; linear
    light for physically right averaging) over the frame exposed from ``frame_t_s`` (top row,
    camera clock) for ``exposure_s``. ``t_ref`` defaults to the model's mid-exposure time."""
    st = settings or RenderSettings()
    cam = model.camera
    W, H = cam.resolution
    img = np.asarray(sharp)
    if img.dtype != np.float32 or img.shape[:2] != (H, W) or img.ndim not in (2, 3):
        raise SynthesisError(f"sharp image must be float32 {H}x{W}[xC] to match the camera, "
                             f"got {img.dtype} {img.shape}")
    t_ref = model.default_reference_time(frame_t_s, exposure_s) if t_ref_s is None \
        else float(t_ref_s)
    plan = plan_samples(model, frame_t_s, exposure_s, t_ref, st)
    tau, wts = plan.tau, plan.weights.astype(np.float32)
    n = tau.size
    border = BORDERS[st.border]
    acc = np.zeros(img.shape, np.float32)
    grid = NodeGrid.build(W, H, node_spacing(model, plan.reach_px, st))
    margin = np.full((grid.v.size, grid.u.size), np.inf)
    homography = cam.readout_s == 0 and not cam.dist
    if homography:
        R = model.rotations(frame_t_s + exposure_s * tau, np.full(n, t_ref))
        K = cam.K
        Kinv = np.linalg.inv(K)
        for Rk, wk in zip(R, wts, strict=True):
            Hk = K @ Rk.T @ Kinv
            w = cv2.warpPerspective(img, Hk, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=border)
            cv2.scaleAdd(w, float(wk), acc, dst=acc)
    for k0 in range(0, n, _TAU_CHUNK):
        mx, my = source_positions(model, frame_t_s, exposure_s, t_ref, grid.u, grid.v,
                                  tau[k0:k0 + _TAU_CHUNK])
        inside = np.minimum(np.minimum(mx, W - 1.0 - mx), np.minimum(my, H - 1.0 - my))
        margin = np.minimum(margin, inside.min(axis=0))
        if homography:
            continue
        # Absolute coordinates: the identity is linear, so bilinear upsampling keeps it exact.
        maps = np.stack([mx, my], axis=-1).astype(np.float32)
        for node_map, wk in zip(maps, wts[k0:k0 + _TAU_CHUNK], strict=True):
            m = grid.upsample(node_map)
            w = cv2.remap(img, m, None, cv2.INTER_LINEAR, borderMode=border)
            cv2.scaleAdd(w, float(wk), acc, dst=acc)
    valid = grid.upsample(margin) >= 0
    return RenderResult(acc, np.ascontiguousarray(valid), tau, plan.step_px,
                        "homography" if homography else "remap", plan.weights)
