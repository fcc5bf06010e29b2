"""The simulated natural-scene rig: a textured far scene instead of the laser grid.

:class:`NaturalRig` is a :class:`~rigs.sim.rig.SimRig` (same true calibration, true motion, gyro
model, sensor noise and session writer) whose frames show a BSDS500 photograph on a plane at
infinity (``z = 1`` in the world frame, the scene direction ``w`` seen at texture pixel
``c_t + s_t · (w_x / w_z, w_y / w_z)``; pure rotation, DESIGN's scene model). With
``depth_m`` the photograph lies on the plane ``z = depth_m`` instead, and with ``speed_mps``
the camera drives towards it along the world ``z`` axis (``c(t) = speed · (t − t_first) · ẑ``,
optionally varied by ``speed_wobble`` at 0.5 Hz): the ray ``c + s w`` meets the plane at
``c + (depth − c_z) / w_z · w``, texture pixel ``c_t + s_t · (c_x + (depth − c_z) w_x / w_z,
…) / depth`` (the "driving" nuisance: forward-motion zoom the rotation model cannot explain).
Pixel ``x`` of row ``r`` at time ``t`` looks along ``w = R_c(t) K⁻¹ x̃`` (``R_c`` from
:meth:`rigs.sim.motion.TrueMotion.orientation`); a blurred frame averages ``n`` such sharp
views at the sub-times ``t_row + exposure · (k + ½) / n`` of each row (rolling shutter:
``t_row = t + readout · r / H``), ``n`` chosen so that consecutive views move by at most
:data:`SUBSTEP_PX`. The texture is bilinearly interpolated (mirrored beyond its edges) at
:data:`TEXEL_PX` camera pixels per texel. Distortion is not rendered: natural presets use
``distortion_coeffs: ()``.

Per row the texture coordinates are ratios of functions linear in the column ``u``
(``w = u · A_row + B_row``): :mod:`rigs.sim.natural_render` evaluates all sub-views of a band
of rows at once and samples them with one ``cv2.remap`` per band;
:meth:`NaturalRig.reference_electrons` is the one-sub-view-at-a-time formulation it is tested
against (float32 rounding apart). The midpoint sum over sub-views is within ~1 DN (8-bit) of
the exposure integral (tests/rigs/sim/test_sim_natural_render.py measures it against 8x finer
sub-views).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blurtrack.io.session import SessionMeta
from rigs.sim.errors import SimError
from rigs.sim.natural_render import (
    ViewGeometry,
    accumulate,
    pad_texture,
    reference_view,
    row_coefficients,
)
from rigs.sim.preset import SimPreset
from rigs.sim.rig import SimRig
from rigs.sim.shake import ShakeTrace

#: Where the project's data README puts BSDS500, relative to the repository's parent.
BSDS_RELPATH = Path("shared") / "data" / "backgrounds" / "bsds500"
#: Camera pixels per texel at the image centre.
TEXEL_PX = 1.5
#: Largest image motion (px) between two sub-views of one exposure.
SUBSTEP_PX = 0.75
MAX_SUBVIEWS = 96
#: Mean scene brightness as a fraction of the full well.
SCENE_LEVEL = 0.55
MAX_TEXTURE_BYTES = 64 * 1024 * 1024


def default_background_dir() -> Path:
    """``<repository>/../shared/data/backgrounds/bsds500`` (may not exist)."""
    return Path(__file__).resolve().parents[3] / BSDS_RELPATH


def pick_background(seed: int, folder: Path | None = None) -> Path:
    """A BSDS500 photograph of the ``val`` split chosen by ``seed`` (``test`` is kept for
    evaluating the deblurring networks)."""
    root = default_background_dir() if folder is None else Path(folder)
    split = root / "val" if (root / "val").is_dir() else root
    files = sorted(p for p in split.glob("*.jpg") if p.is_file())
    if not files:
        raise SimError(f"no background photographs (*.jpg) found in {split}")
    return files[int(seed) % len(files)]


def load_texture(path: Path) -> np.ndarray:
    """A photograph as float32 gray in ``[0, 1]`` ``(Ht, Wt)``."""
    p = Path(path)
    if not p.is_file():
        raise SimError(f"background {p} does not exist")
    if p.stat().st_size > MAX_TEXTURE_BYTES:
        raise SimError(f"background {p} is larger than {MAX_TEXTURE_BYTES >> 20} MiB")
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if img is None or min(img.shape) < 16:
        raise SimError(f"background {p} does not decode as an image of at least 16x16")
    return img.astype(np.float32) / 255.0


class NaturalRig(SimRig):
    """A simulated rig filming a textured far scene (see the module docstring).

    Args:
        background: a photograph, or ``None`` for :func:`pick_background` by ``seed``.
        depth_m: distance of the textured plane (``None``: at infinity, pure rotation).
        speed_mps: forward speed towards the plane (needs ``depth_m``).
        speed_wobble: relative speed variation (``speed · (1 + wobble · sin(2π · 0.5 Hz · t))``).
    """

    def __init__(
        self,
        preset: SimPreset,
        seed: int,
        n_frames: int,
        shake: ShakeTrace | str | Path | None = None,
        background: str | Path | None = None,
        depth_m: float | None = None,
        speed_mps: float = 0.0,
        speed_wobble: float = 0.0,
    ) -> None:
        if preset.distortion_coeffs:
            raise SimError("the natural-scene renderer draws no lens distortion")
        if depth_m is not None and not (math.isfinite(depth_m) and depth_m > 0):
            raise SimError(f"depth_m must be a positive distance, got {depth_m}")
        if speed_mps and depth_m is None:
            raise SimError("a forward speed needs a plane at finite depth (depth_m)")
        if not (math.isfinite(speed_mps) and 0 <= abs(speed_wobble) < 1):
            raise SimError("speed_mps must be finite and speed_wobble in (-1, 1)")
        super().__init__(preset, seed, n_frames, shake=shake)
        self.depth_m = depth_m
        self.speed_mps = float(speed_mps)
        self.speed_wobble = float(speed_wobble)
        self._t_first = float(self.frame_times_ns[0]) * 1e-9
        if depth_m is not None:
            t_end = float(self.frame_times_ns[-1]) * 1e-9 + 0.1
            travel = float(self.position(np.array([t_end]))[0, 2])
            if travel >= 0.5 * depth_m:
                raise SimError(
                    f"the camera would drive {travel:.1f} m, more than half way to the plane "
                    f"at {depth_m} m"
                )
        self.background = Path(background) if background else pick_background(seed)
        self.texture = load_texture(self.background)
        fx = self.camera.intrinsics[0]
        self.texel_scale = fx / TEXEL_PX  # texels per unit tangent
        Ht, Wt = self.texture.shape
        self.texture_centre = ((Wt - 1) / 2, (Ht - 1) / 2)
        self._padded, self._pad = pad_texture(self.texture)
        level = SCENE_LEVEL * preset.full_well_e
        self._scene_e = level / max(float(np.mean(self.texture)), 1e-3)

    # ------------------------------------------------------------- guesses
    def nominal_meta(self) -> SessionMeta:
        m = super().nominal_meta()
        return SessionMeta(m.camera, m.imu, "natural", extra=m.extra)

    def position(self, t_s: np.ndarray) -> np.ndarray:
        """Camera centre ``(M, 3)`` in the world (m) at camera times ``(M,)``."""
        t = np.asarray(t_s, float).reshape(-1) - self._t_first
        f = 2 * math.pi * 0.5
        z = self.speed_mps * (t + self.speed_wobble * (1 - np.cos(f * t)) / f)
        return np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)

    # ------------------------------------------------------------- render
    def _geometry(self, t: np.ndarray) -> ViewGeometry:
        """Map coefficients for row times ``t (n, H)`` (row ``r`` of sub-view ``k``)."""
        n, H = t.shape
        flat = t.reshape(-1)
        R = self.motion.orientation(flat).reshape(n, H, 3, 3)
        c = self.position(flat).reshape(n, H, 3) if self.depth_m is not None else None
        px, py = self._pad
        centre = (self.texture_centre[0] + px, self.texture_centre[1] + py)
        return row_coefficients(
            R, self.camera.intrinsics, self.texel_scale, centre, c, self.depth_m
        )

    def _render(self, t: np.ndarray) -> np.ndarray:
        """Sum of the sharp views at row times ``t (n, H)``, ``(H, W)`` float32."""
        return accumulate(self._padded, self._geometry(t), self.camera.width, self.texel_scale)

    def _view(self, R_rows: np.ndarray, c_rows: np.ndarray | None = None) -> np.ndarray:
        """Sharp texture values ``(H, W)`` for per-row orientations ``R_rows (H, 3, 3)`` and
        camera centres ``c_rows (H, 3)`` (only with a plane at finite depth): the reference
        formulation, one full-frame sub-view (:func:`rigs.sim.natural_render.reference_view`)."""
        return reference_view(
            self.texture,
            R_rows,
            self.camera.intrinsics,
            self.camera.width,
            self.texel_scale,
            self.texture_centre,
            c_rows,
            self.depth_m,
        )

    def subviews(self, t_start_s: float) -> int:
        """Sub-views of the frame starting at ``t_start_s`` (see :data:`SUBSTEP_PX`)."""
        p = self.preset
        span = p.exposure_s + self.camera.readout_s
        t = t_start_s + np.linspace(0.0, span, 64)
        w = np.linalg.norm(self.omega_cam_at(t), axis=1).max()
        fx, fy = self.camera.intrinsics[:2]
        diag = math.hypot(self.camera.width, self.camera.height) / 2
        px = w * p.exposure_s * (max(fx, fy) + diag * diag / max(fx, fy))
        return int(np.clip(math.ceil(px / SUBSTEP_PX), 2, MAX_SUBVIEWS))

    def render_electrons(self, t_start_s: float) -> np.ndarray:
        """Mean photo-electrons ``(H, W)`` of the blurred frame (no ambient, no noise)."""
        p, cam = self.preset, self.camera
        H = cam.height
        n = self.subviews(t_start_s)
        row_t = t_start_s + cam.readout_s * np.arange(H) / H
        t = row_t[None, :] + p.exposure_s * (np.arange(n)[:, None] + 0.5) / n
        return self._render(t) * np.float32(self._scene_e / n)

    def reference_electrons(self, t_start_s: float, n: int | None = None) -> np.ndarray:
        """:meth:`render_electrons` one full-frame sub-view at a time (the reference the
        banded renderer is tested against), with ``n`` sub-views (default :meth:`subviews`)."""
        p, cam = self.preset, self.camera
        H = cam.height
        n = self.subviews(t_start_s) if n is None else int(n)
        row_t = t_start_s + cam.readout_s * np.arange(H) / H
        acc = np.zeros((H, cam.width), np.float32)
        for k in range(n):
            t_k = row_t + p.exposure_s * (k + 0.5) / n
            acc += self._view(self.motion.orientation(t_k), self.position(t_k))
        return acc * np.float32(self._scene_e / n)

    def sharp_electrons(self, t_ref_s: float) -> np.ndarray:
        """The scene without motion blur, every row seen at ``t_ref_s``."""
        H = self.camera.height
        R = np.broadcast_to(self.motion.orientation(np.array([t_ref_s]))[0], (H, 3, 3))
        c = np.broadcast_to(self.position(np.array([t_ref_s])), (H, 3))
        return self._view(np.ascontiguousarray(R), np.ascontiguousarray(c)) * np.float32(
            self._scene_e
        )

    # --------------------------------------------------------------- truth
    def frame_truth(self, index: int) -> dict[str, Any]:
        ts_ns = int(self.frame_times_ns[index])
        return {
            "index": int(index),
            "timestamp_ns": ts_ns,
            "exposure_ns": self.exposure_ns,
            "subviews": self.subviews(ts_ns * 1e-9),
            "streaks": [],
        }

    def simulator_info(self) -> dict[str, Any]:
        info = super().simulator_info()
        info.pop("dots", None)
        info["scene"] = {
            "kind": "natural",
            "model": "far plane (pure rotation)"
            if self.depth_m is None
            else "plane at finite depth, forward translation",
            "depth_m": self.depth_m,
            "speed_mps": self.speed_mps,
            "speed_wobble": self.speed_wobble,
            "background": self.background.name,
            "texel_px": TEXEL_PX,
            "texture_size": list(self.texture.shape[::-1]),
        }
        return info
