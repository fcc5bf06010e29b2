"""Inter-frame rotations with the camera's forward translation as a nuisance, chosen by the data.

:func:`calib.axes.rotations.fit_rotation` assumes a far scene: bearings turn by one rotation between
frames. Filmed from a moving vehicle, near points also slide away from the focus of
expansion: at 720p a plane 8 m away, 0.1 m closer per frame, moves points 1.25 % of their
distance from it (8 px at the image edge), which the pure-rotation fit cannot explain and
the axis search reads as a gyro that does not match.

Per frame pair :func:`fit_rotation_translating` fits two models to the same bearings:

* pure rotation, ``b ≈ R a``;
* rotation after a zoom about the principal point, ``b ≈ R · n((1 + s) x_a, (1 + s) y_a, 1)``
  (``x_a, y_a`` normalised coordinates, ``n`` normalisation): forward travel along the
  optical axis towards points at similar depths, ``s ≈ travel / depth``; ``s`` by a linear
  fit refined by three rotation fits, ``R`` by :func:`calib.axes.rotations.fit_rotation`.

The zoom model is taken only when the rotation-only median residual exceeds
:data:`MIN_RESIDUAL_FRACTION` of the inlier gate *and* :data:`RESIDUAL_RATIO` times the zoom
model's (both 2-D, the zoom model has one parameter more), and a linear fit of the same two
models (:func:`zoom_estimate`, cheap) says so first: a far scene keeps pure rotation.

Why not a free translation direction (an essential matrix, or a free epipole per pair): for a
scene at nearly one depth, a sideways translation moves every point alike, exactly as a small
pan or tilt does, so a free direction trades against the rotation the axis search needs
(``cv2.findEssentialMat`` + ``cv2.recoverPose`` on the simulated 720p drive, seed 0: epipolar
residuals of 0.1–0.3 px with rotations 5–22 px from the rotation-only fit's and translation
directions up to 70° off the direction of travel). Fixing the focus of expansion at the
principal point removes that freedom; a heading ``Δe`` px off the optical axis biases a pair's
rotation by about ``s · Δe`` px (0.0125 · 100 px = 1.25 px on that drive), small beside the
rotations the search scores. The continuous fit models the translation properly afterwards
(:mod:`calib.natural.motion`). Either way the images alone measure the rotation: a wrong gyro
still predicts it badly and is refused by :func:`calib.axes.search.check_axes`.
"""

from __future__ import annotations

import numpy as np

from calib.axes.rotations import fit_rotation

#: Rotation-only median residual / zoom-model median residual above which a pair is
#: translating.
RESIDUAL_RATIO = 1.5
#: Rotation-only median residual, as a fraction of the inlier gate, below which a pair is
#: never called translating (0.5 px of the 2 px gate of
#: :func:`calib.axes.rotations.rotations_from_pairs`).
MIN_RESIDUAL_FRACTION = 0.25
#: Largest zoom considered per frame pair (8 % of the distance from the principal point).
ZOOM_RANGE = 0.08
#: Refinement step of the zoom around its linear estimate.
ZOOM_STEP = 0.0015


def zoomed(a: np.ndarray, s: float) -> np.ndarray:
    """Unit bearings ``a (N, 3)`` (in front of the camera) zoomed by ``1 + s`` about the
    optical axis."""
    x = a[:, :2] / a[:, 2:] * (1.0 + s)
    out = np.concatenate([x, np.ones((a.shape[0], 1))], axis=1)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _median_residual(a: np.ndarray, b: np.ndarray, R: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(a @ R.T - b, axis=1)))


def _huber_median(A: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares ``A x ≈ r`` (x rows then y rows of N points) with two Huber
    reweightings: the solution and the median 2-D residual."""
    n = len(r) // 2
    w = np.ones(n)
    for _ in range(3):
        ww = np.concatenate([w, w])
        sol = np.linalg.lstsq(A * ww[:, None], r * ww, rcond=None)[0]
        e = np.hypot(*(A @ sol - r).reshape(2, -1))
        k = 2.0 * max(float(np.median(e)), 1e-12)
        w = np.sqrt(np.minimum(1.0, k / np.maximum(e, 1e-300)))
    return sol, float(np.median(e))


def zoom_estimate(a: np.ndarray, b: np.ndarray, R0: np.ndarray) -> tuple[float, float]:
    """Linear zoom ``s`` of bearings ``a`` into ``b (N, 3)`` once ``a`` is turned by the
    rotation-only estimate ``R0``, and how much it explains: the normalised-coordinate
    displacement left is a small rotation's motion field plus ``s`` times the position, fitted
    robustly (:func:`_huber_median`) with and without the zoom. Returns ``s`` and the ratio of
    the two median residuals (without / with).

    A scan of a RANSAC rotation fit over 50 zooms cost 0.37 s per 720p frame pair (111 s for
    10 s of video); this estimate screens the pairs (far scenes rarely pass) and
    :func:`fit_rotation_zoom` refines its ``s`` with about 4 rotation fits."""
    ar = a @ R0.T
    x, xb = ar[:, :2] / ar[:, 2:], b[:, :2] / b[:, 2:]
    X, Y = x[:, 0], x[:, 1]
    A = np.concatenate(
        [
            np.stack([X * Y, -(1 + X**2), Y, X], axis=1),
            np.stack([1 + Y**2, -X * Y, -X, Y], axis=1),
        ]
    )
    r = np.concatenate([xb[:, 0] - X, xb[:, 1] - Y])
    sol, e_zoom = _huber_median(A, r)
    _, e_rot = _huber_median(A[:, :3], r)
    return float(np.clip(sol[3], -ZOOM_RANGE, ZOOM_RANGE)), e_rot / max(e_zoom, 1e-15)


def fit_rotation_zoom(
    a: np.ndarray,
    b: np.ndarray,
    threshold_rad: float,
    seed: int = 0,
    R0: np.ndarray | None = None,
    s0: float | None = None,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Rotation, inlier mask, zoom ``s`` and median residual (rad) of the zoom model: ``s``
    from :func:`zoom_estimate`, refined by a parabola through three rotation fits
    :data:`ZOOM_STEP` apart. ``R0``, ``s0``: the pair's rotation-only fit and
    linear zoom, when already made."""

    def at(s: float) -> tuple[float, np.ndarray, np.ndarray]:
        az = zoomed(a, s)
        R, inl = fit_rotation(az, b, threshold_rad, seed=seed)
        return _median_residual(az, b, R), R, inl

    if s0 is None:
        if R0 is None:
            R0, _ = fit_rotation(a, b, threshold_rad, seed=seed)
        s0, _ = zoom_estimate(a, b, R0)
    grid = [s0 - ZOOM_STEP, s0, s0 + ZOOM_STEP]
    fits = [at(s) for s in grid]
    (r_m, _, _), (r_0, _, _), (r_p, _, _) = fits
    curv = r_m - 2 * r_0 + r_p
    if curv > 0:
        step = 0.5 * ZOOM_STEP * (r_m - r_p) / curv
        grid.append(s0 + float(np.clip(step, -2 * ZOOM_STEP, 2 * ZOOM_STEP)))
        fits.append(at(grid[-1]))
    k = int(np.argmin([f[0] for f in fits]))
    r, R, inl = fits[k]
    return R, inl, float(grid[k]), r


def fit_rotation_translating(
    a: np.ndarray, b: np.ndarray, threshold_rad: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The inter-frame rotation of unit bearings ``a, b (N, 3)``, with forward translation as
    a nuisance when the data need it (see the module docstring): ``R (3, 3)``, inlier mask
    and whether the zoom model was chosen. ``threshold_rad``: the inlier gate (px / fx)."""
    R0, inl0 = fit_rotation(a, b, threshold_rad, seed=seed)
    r_rot = _median_residual(a, b, R0)
    if r_rot <= MIN_RESIDUAL_FRACTION * threshold_rad or np.any(a[:, 2] <= 0):
        return R0, inl0, False
    if np.any(b[:, 2] <= 0):
        return R0, inl0, False
    s0, ratio = zoom_estimate(a, b, R0)
    if ratio <= RESIDUAL_RATIO:
        return R0, inl0, False  # the linear screen: the zoom explains too little
    R, inl, _, r_zoom = fit_rotation_zoom(a, b, threshold_rad, seed, R0, s0)
    if r_rot <= RESIDUAL_RATIO * r_zoom:
        return R0, inl0, False
    return R, inl, True
