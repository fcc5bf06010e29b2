"""Laser dots fixed in the world, their image positions and the true streak of each dot.

The projector is a diffractive dot matrix: directions on a regular angular grid, fixed in the
world frame of :class:`~rigs.sim.motion.TrueMotion`. Dot ``j`` at world direction ``d_j`` is seen
at ``π(K R_c(t)ᵀ d_j)`` (pure rotation, docs/conventions.md). A streak's start is where the dot is
when its
own row starts exposing — the fixed point of ``t = t_frame + readout · v(t) / H`` — and its end
where it is when that row stops (``+ exposure``); in between the dot traces the centre line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blurtrack.geometry.camera import Camera
from blurtrack.geometry.kernels import project_c
from rigs.sim.errors import SimError
from rigs.sim.motion import TrueMotion

#: Fixed-point iterations (at most) for the rolling-shutter row time; stops at 1e-13 s (or the
#: float64 resolution of the clock value).
ROW_TIME_MAX_ITER = 60
#: Dense samples per streak used for visibility, length and the centre line.
DENSE_SAMPLES = 129  # odd: the middle sample is the time midpoint
#: Most centre-line points written per streak.
MAX_CENTERLINE_POINTS = 32
#: Target spacing of centre-line points (px); keeps truth.yaml small enough to load fast.
CENTERLINE_SPACING_PX = 4.0
#: A streak is ``inside`` when all of it lies this many pixels inside the image.
INSIDE_MARGIN_PX = 3.0


def dot_directions(
    cols: int,
    rows: int,
    fill: float,
    width: int,
    height: int,
    focal_px: float,
    jitter: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Unit world directions ``(rows * cols, 3)`` of a regular angular dot grid.

    Dot ``j = row * cols + col``; the grid spans ``fill`` of a ``width x height`` view at
    ``focal_px`` when the camera looks along the world z axis. ``jitter > 0`` moves each dot by
    up to that fraction of the grid spacing in each angle (uniformly, from ``rng``).

    >>> d = dot_directions(3, 1, 1.0, 200, 100, 100.0)
    >>> np.round(np.degrees(np.arctan2(d[:, 0], d[:, 2])), 6).tolist()
    [-45.0, 0.0, 45.0]
    """
    ax = math.atan(fill * (width / 2) / focal_px)
    ay = math.atan(fill * (height / 2) / focal_px)
    alpha_x = np.linspace(-ax, ax, cols) if cols > 1 else np.zeros(1)
    alpha_y = np.linspace(-ay, ay, rows) if rows > 1 else np.zeros(1)
    AX, AY = np.meshgrid(alpha_x, alpha_y)
    if jitter > 0:
        if rng is None:
            raise SimError("dot jitter needs a random generator")
        sx = 2 * ax / max(cols - 1, 1)
        sy = 2 * ay / max(rows - 1, 1)
        AX = AX + rng.uniform(-jitter, jitter, AX.shape) * sx
        AY = AY + rng.uniform(-jitter, jitter, AY.shape) * sy
    X, Y = np.tan(AX), np.tan(AY)
    d = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def dot_pixels(
    motion: TrueMotion,
    camera: Camera,
    directions: np.ndarray,
    t_s: np.ndarray,
    dot_index: np.ndarray,
) -> np.ndarray:
    """Pixel positions ``(S, 2)`` of dots ``dot_index (S,)`` at camera times ``t_s (S,)``.

    Dots behind the camera come back as NaN.
    """
    R = motion.orientation(t_s)
    c = np.einsum("sji,sj->si", R, directions[np.asarray(dot_index)])
    z = c[:, 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    u, v = project_c(c[:, 0], c[:, 1], zs, camera.intrinsics, camera.dist)
    return np.where(front[:, None], np.stack([u, v], axis=1), np.nan)


def row_time(
    motion: TrueMotion,
    camera: Camera,
    directions: np.ndarray,
    frame_t_s: float,
    offset_s: float,
    dot_index: np.ndarray,
) -> np.ndarray:
    """Camera times ``(J,)`` solving ``t = frame_t + readout · v_j(t) / H + offset``.

    Fixed-point iteration on the true motion; it contracts while the dot's vertical speed stays
    under ``H / readout`` px/s (any hand shake).
    """
    idx = np.asarray(dot_index)
    t = np.full(idx.size, frame_t_s + offset_s + camera.readout_s / 2)
    if camera.readout_s == 0.0:
        return np.full(idx.size, frame_t_s + offset_s)
    for _ in range(ROW_TIME_MAX_ITER):
        v = dot_pixels(motion, camera, directions, t, idx)[:, 1]
        t_new = frame_t_s + offset_s + camera.readout_s * v / camera.height
        if not np.all(np.isfinite(t_new)):
            raise SimError("a dot went behind the camera; reduce the motion or dot_fill")
        # 1e-13 s, or a few float64 steps at large clock values
        done = np.max(np.abs(t_new - t)) <= max(1e-13, 8 * float(np.spacing(np.max(np.abs(t)))))
        t = t_new
        if done:
            break
    else:
        raise SimError(
            "rolling-shutter row times did not converge (motion too fast for the readout)"
        )
    return t


@dataclass(frozen=True)
class TrueFrameStreaks:
    """True streaks of all dots in one frame (camera clock, seconds; pixels).

    ``path`` holds ``DENSE_SAMPLES`` positions per dot equally spaced in time from ``t_start``
    to ``t_end``; ``ref`` the positions at ``t_ref_s``.
    """

    t_ref_s: float
    t_start_s: np.ndarray  # (J,)
    t_end_s: np.ndarray  # (J,)
    path: np.ndarray  # (J, DENSE_SAMPLES, 2)
    ref: np.ndarray  # (J, 2)
    visible: np.ndarray  # (J,) bool: some of the streak lies in the image
    inside: np.ndarray  # (J,) bool: all of it at least INSIDE_MARGIN_PX inside
    length_px: np.ndarray  # (J,) arc length of the path

    @property
    def start(self) -> np.ndarray:
        return self.path[:, 0]

    @property
    def end(self) -> np.ndarray:
        return self.path[:, -1]

    @property
    def mid(self) -> np.ndarray:
        """``(J, 2)`` positions at the time midpoint ``(t_start + t_end) / 2``: the point that
        halves the streak's light (``DENSE_SAMPLES`` is odd)."""
        return self.path[:, DENSE_SAMPLES // 2]

    def centerline(self, j: int) -> np.ndarray:
        """At most 32 points ``(n, 2)``, start to end, equally spaced in time, about one per
        ``CENTERLINE_SPACING_PX`` of length."""
        n = int(
            np.clip(
                math.ceil(self.length_px[j] / CENTERLINE_SPACING_PX) + 1, 2, MAX_CENTERLINE_POINTS
            )
        )
        pick = np.round(np.linspace(0, DENSE_SAMPLES - 1, n)).astype(int)
        return self.path[j, pick]


def frame_streaks(
    motion: TrueMotion,
    camera: Camera,
    directions: np.ndarray,
    frame_t_s: float,
    exposure_s: float,
    t_ref_s: float,
) -> TrueFrameStreaks:
    """The true streaks of every dot in the frame that starts at ``frame_t_s``."""
    J = directions.shape[0]
    idx = np.arange(J)
    t0 = row_time(motion, camera, directions, frame_t_s, 0.0, idx)
    t1 = row_time(motion, camera, directions, frame_t_s, exposure_s, idx)
    frac = np.linspace(0.0, 1.0, DENSE_SAMPLES)
    times = t0[:, None] + (t1 - t0)[:, None] * frac[None, :]
    path = dot_pixels(
        motion, camera, directions, times.ravel(), np.repeat(idx, DENSE_SAMPLES)
    ).reshape(J, DENSE_SAMPLES, 2)
    ref = dot_pixels(motion, camera, directions, np.full(J, t_ref_s), idx)
    W, H = camera.resolution
    x, y = path[..., 0], path[..., 1]
    ok = np.isfinite(x) & np.isfinite(y)
    visible = np.any(ok & (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5), axis=1)
    m = INSIDE_MARGIN_PX
    inside = np.all(ok & (x >= m) & (x <= W - 1 - m) & (y >= m) & (y <= H - 1 - m), axis=1)
    length = np.linalg.norm(np.diff(path, axis=1), axis=2).sum(axis=1)
    return TrueFrameStreaks(float(t_ref_s), t0, t1, path, ref, visible, inside, length)
