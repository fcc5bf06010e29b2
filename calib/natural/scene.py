"""Scene clusters of natural-scene tracks: the tracks of one part of the scene, whole session.

Under hand shake a far scene stays almost where it is in the image for the whole recording:
a textured patch is tracked in frame pair after frame pair, at nearly the same pixel and
under similar blur. A tracking error that belongs to the patch (its texture pulls Lucas–
Kanade the same way every time) therefore repeats in every pair that sees it, for seconds,
far beyond the neighbouring pairs that the frame-pair and block sandwiches of
:mod:`calib.natural.sigma` / :mod:`calib.natural.scale` group together. Such an error is
common to a session but not to all of its tracks, so a sandwich clustered by *scene cell*
sees it: each track's start point is carried by the fitted calibration and the gyro into the
view of the first frame (:func:`scene_pixels`), and tracks whose scene pixels share a
:data:`SCENE_CELL_PX` square form one cluster (:func:`scene_cells`). Tracks of the same
patch in different pairs then share a cluster; the cluster-robust variance grows where their
errors are alike and not where they are independent.
"""

from __future__ import annotations

import numpy as np

from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.rotation import so3_exp
from calib.data import StreakSet

#: Side of a scene cell (px of the first frame's view): several tracker windows (21 px), so
#: one patch's tracks fall into one cell despite the small errors of the carried positions.
SCENE_CELL_PX = 64.0
#: Fewest scene cells for the scene sandwich: its meat has rank at most the number of
#: clusters and a relative noise of about √(2 / C), so it needs several times the ~20 fitted
#: parameters (a 720p view has ~220 cells; 320×180 only ~22, and there it is left out).
SCENE_MIN_CELLS = 100


def _camera_rates(gyro: GyroTrace, calib: Calibration) -> np.ndarray:
    """``(n, 3)`` bias-corrected rates in the camera frame (scale error neglected: a few
    tenths of a percent of the angle)."""
    return (np.asarray(gyro.omega_radps, float) - calib.gyro_bias_radps) @ calib.R_cam_imu.T


def camera_orientations(gyro: GyroTrace, calib: Calibration) -> np.ndarray:
    """``(n, 3, 3)`` camera-to-reference rotations at the gyro's samples (IMU clock, as
    ``gyro``): the camera-frame rates integrated from the first sample, each held until the
    next sample."""
    w = _camera_rates(gyro, calib)
    dt = np.diff(np.asarray(gyro.t_s, float))
    steps = so3_exp(w[:-1] * dt[:, None])
    R = np.empty((len(w), 3, 3))
    R[0] = np.eye(3)
    for k in range(len(steps)):
        R[k + 1] = R[k] @ steps[k]
    return R


def scene_pixels(streaks: StreakSet, gyro: GyroTrace, calib: Calibration) -> np.ndarray:
    """``(N, 2)`` where each track's start point would be seen by the camera at the gyro's
    first sample (pinhole, ``calib``'s intrinsics; ``gyro`` on the streaks' time origin)."""
    fx, fy, cx, cy = calib.camera.intrinsics
    H = calib.camera.height
    t_imu = (
        np.asarray(streaks.frame_t_s, float)
        + calib.camera.readout_s * np.asarray(streaks.rows, float)[:, 0] / H
        + calib.timeshift_cam_imu_s
    )
    R, w, ts = camera_orientations(gyro, calib), _camera_rates(gyro, calib), np.asarray(gyro.t_s)
    k = np.clip(np.searchsorted(ts, t_imu, side="right") - 1, 0, len(R) - 1)
    Rt = R[k] @ so3_exp(w[k] * (t_imu - ts[k])[:, None])  # on from the sample before
    p = np.asarray(streaks.start, float)
    ray = np.stack([(p[:, 0] - cx) / fx, (p[:, 1] - cy) / fy, np.ones(len(p))], axis=1)
    world = np.einsum("nij,nj->ni", Rt, ray)
    z = np.maximum(world[:, 2], 1e-6)
    return np.stack([fx * world[:, 0] / z + cx, fy * world[:, 1] / z + cy], axis=1)


def cluster_meat(J: np.ndarray, r: np.ndarray, w: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """Meat ``Σ_c g_c g_cᵀ · C/(C−1)`` of a cluster-robust sandwich: ``g_c`` the weighted
    score ``Σ_{i∈c} w_i J_iᵀ r_i`` of cluster ``c`` (``J (N, k, p)``, ``r (N, k)``, ``w (N,)``
    residuals of ``k`` coordinates each), ``C`` clusters."""
    g = np.einsum("n,nki,nk->ni", w, J, r)
    uniq, inv = np.unique(cluster, return_inverse=True)
    G = np.zeros((uniq.size, J.shape[2]))
    np.add.at(G, inv, g)
    nc = uniq.size
    return G.T @ G * (nc / max(nc - 1, 1))


def cells_of(pixels: np.ndarray, cell_px: float = SCENE_CELL_PX) -> np.ndarray:
    """``(N,)`` integer label of the ``cell_px`` square holding each pixel.

    >>> cells_of(np.array([[1.0, 2.0], [63.0, 10.0], [65.0, 2.0]])).tolist()
    [0, 0, 1]
    """
    ij = np.floor(np.asarray(pixels, float) / cell_px).astype(np.int64)
    ij -= ij.min(axis=0) if len(ij) else 0
    return ij[:, 1] * (int(ij[:, 0].max(initial=0)) + 1) + ij[:, 0]


def scene_cells(
    streaks: StreakSet, gyro: GyroTrace, calib: Calibration, cell_px: float = SCENE_CELL_PX
) -> np.ndarray:
    """``(N,)`` scene-cell cluster of each track (module docstring)."""
    return cells_of(scene_pixels(streaks, gyro, calib), cell_px)
