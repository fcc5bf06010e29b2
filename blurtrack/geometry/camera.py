"""Pinhole camera with optional radtan distortion and rolling-shutter row timing.

Conventions (docs/conventions.md): camera frame x right, y down, z forward; pixel (0, 0) is the
centre of
the top-left pixel; intrinsics ``[fx, fy, cx, cy]`` in pixels; distortion ``none`` or ``radtan``
(OpenCV ``k1 k2 p1 p2``). Row ``r`` of an ``H``-row frame stamped ``t`` starts exposing at
``t + readout_s * r / H``. The projection maths is :mod:`blurtrack.geometry.kernels`'s, shared
with the
CasADi calibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from blurtrack.errors import GeometryError
from blurtrack.geometry.kernels import project_c, row_start_c, unproject_c

DISTORTION_MODELS = ("none", "radtan")
#: Largest image side accepted (px), and largest focal length per image side (a 0.01-degree
#: field of view): numbers beyond them are typos or hostile, and would hang the models.
MAX_SIDE_PX = 65536
MAX_FOCAL_PER_SIDE = 10_000


@dataclass(frozen=True)
class Camera:
    """Intrinsics, distortion and shutter timing of one camera.

    >>> cam = Camera(resolution=(640, 480), intrinsics=(500.0, 500.0, 319.5, 239.5))
    >>> cam.project(np.array([[0.0, 0.0, 2.0]])).tolist()
    [[319.5, 239.5]]
    """

    resolution: tuple[int, int]
    intrinsics: tuple[float, float, float, float]
    distortion_model: str = "none"
    distortion_coeffs: tuple[float, ...] = ()
    readout_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "resolution", tuple(int(v) for v in self.resolution))
        object.__setattr__(self, "intrinsics", tuple(float(v) for v in self.intrinsics))
        object.__setattr__(
            self, "distortion_coeffs", tuple(float(v) for v in self.distortion_coeffs)
        )
        object.__setattr__(self, "readout_s", float(self.readout_s))
        w, h = self.resolution if len(self.resolution) == 2 else (0, 0)
        if len(self.resolution) != 2 or w <= 0 or h <= 0:
            raise GeometryError(
                f"camera resolution must be [width, height] > 0, got {list(self.resolution)}"
            )
        if len(self.intrinsics) != 4 or not all(math.isfinite(v) for v in self.intrinsics):
            raise GeometryError(
                f"camera intrinsics must be 4 finite numbers [fx, fy, cx, cy], "
                f"got {list(self.intrinsics)}"
            )
        if self.intrinsics[0] <= 0 or self.intrinsics[1] <= 0:
            raise GeometryError(f"focal lengths must be positive, got {self.intrinsics[:2]}")
        if max(w, h) > MAX_SIDE_PX:
            raise GeometryError(f"camera resolution {w}x{h} is over {MAX_SIDE_PX} px a side")
        side = max(w, h)
        fx, fy, cx, cy = self.intrinsics
        if max(fx, fy) > MAX_FOCAL_PER_SIDE * side or max(abs(cx), abs(cy)) > 10 * side:
            raise GeometryError(
                f"camera intrinsics {list(self.intrinsics)} are out of range for {w}x{h} "
                f"(focal lengths up to {MAX_FOCAL_PER_SIDE}x, principal point within 10x "
                "the image size)"
            )
        if self.distortion_model not in DISTORTION_MODELS:
            raise GeometryError(
                f"distortion_model must be one of {DISTORTION_MODELS}, got "
                f"{self.distortion_model!r}"
            )
        want = 0 if self.distortion_model == "none" else 4
        if len(self.distortion_coeffs) != want:
            raise GeometryError(
                f"distortion_model {self.distortion_model} takes {want} "
                f"coefficients, got {len(self.distortion_coeffs)}"
            )
        if not all(math.isfinite(v) and abs(v) <= 1e3 for v in self.distortion_coeffs):
            raise GeometryError("distortion coefficients must be finite, at most 1e3 in size")
        if not (math.isfinite(self.readout_s) and 0.0 <= self.readout_s < 1.0):
            raise GeometryError(f"readout_s must be in [0, 1) s, got {self.readout_s}")

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    @property
    def K(self) -> np.ndarray:
        """Camera matrix (3, 3)."""
        fx, fy, cx, cy = self.intrinsics
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> tuple[float, ...]:
        """Distortion coefficients as the model functions take them (``()`` for none)."""
        return self.distortion_coeffs

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(N, 3)`` (z > 0) to pixels ``(N, 2)``."""
        p = np.asarray(points_cam, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise GeometryError(f"points must have shape (N, 3), got {p.shape}")
        u, v = project_c(p[:, 0], p[:, 1], p[:, 2], self.intrinsics, self.dist)
        return np.stack([u, v], axis=1)

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` to camera-frame rays ``(N, 3)`` with ``z = 1``."""
        px = np.asarray(pixels, dtype=float)
        if px.ndim != 2 or px.shape[1] != 2:
            raise GeometryError(f"pixels must have shape (N, 2), got {px.shape}")
        return np.stack(unproject_c(px[:, 0], px[:, 1], self.intrinsics, self.dist), axis=1)

    def row_start_s(self, frame_t_s: Any, rows: Any) -> Any:
        """Start of exposure (camera clock, s) of image rows (continuous row coordinates)."""
        return row_start_c(frame_t_s, np.asarray(rows, dtype=float), self.readout_s, self.height)

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by ``factor`` (pixel-centre convention)."""
        fx, fy, cx, cy = self.intrinsics
        w, h = self.resolution
        return Camera(
            resolution=(round(w * factor), round(h * factor)),
            intrinsics=(
                fx * factor,
                fy * factor,
                (cx + 0.5) * factor - 0.5,
                (cy + 0.5) * factor - 0.5,
            ),
            distortion_model=self.distortion_model,
            distortion_coeffs=self.distortion_coeffs,
            readout_s=self.readout_s,
        )


#: Turning the image by 180 degrees about the optical axis reverses the camera's x and y
#: axes: a camera-frame vector ``v`` is ``TURN_180 @ v`` in the turned camera's frame.
TURN_180 = np.diag([-1.0, -1.0, 1.0])


def turned_camera(camera: Camera) -> Camera:
    """``camera`` with its images turned by 180 degrees (a sensor that reads its bottom row
    first stored so that it reads the top row first): the principal point at ``(W - 1 - cx,
    H - 1 - cy)``, a radtan distortion's tangential terms negated (the radial ones are even
    in ``(x, y)``); focal lengths and readout as they are. A point ``X`` (camera frame)
    projects to ``(W - 1 - u, H - 1 - v)`` through the turned camera at ``TURN_180 @ X``.
    Turned twice it is ``camera`` again."""
    w, h = camera.resolution
    fx, fy, cx, cy = camera.intrinsics
    coeffs = tuple(camera.distortion_coeffs)
    if camera.distortion_model == "radtan":
        k1, k2, p1, p2 = coeffs
        coeffs = (k1, k2, -p1, -p2)
    return Camera(
        resolution=(w, h),
        intrinsics=(fx, fy, w - 1 - cx, h - 1 - cy),
        distortion_model=camera.distortion_model,
        distortion_coeffs=coeffs,
        readout_s=camera.readout_s,
    )
