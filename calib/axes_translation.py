"""Inter-frame rotations with the camera's forward translation as a nuisance, chosen by the data.

:func:`calib.axes.fit_rotation` assumes a far scene: bearings turn by one rotation between
frames. Filmed from a moving vehicle, near points also slide away from the focus of
expansion: at 720p a plane 8 m away, 0.1 m closer per frame, moves points 1.25 % of their
distance from it (8 px at the image edge), which the pure-rotation fit cannot explain and
the axis search reads as a gyro that does not match.

Per frame pair :func:`fit_rotation_translating` fits two models to the same bearings:

* pure rotation, ``b ≈ R a``;
* rotation after a zoom about the principal point, ``b ≈ R · n((1 + s) x_a, (1 + s) y_a, 1)``
  (``x_a, y_a`` normalised coordinates, ``n`` normalisation): forward travel along the
  optical axis towards points at similar depths, ``s ≈ travel / depth``; ``s`` by a coarse
  then fine scan, ``R`` by :func:`calib.axes.fit_rotation` at each.

The zoom model is taken only when the rotation-only median residual exceeds
:data:`MIN_RESIDUAL_FRACTION` of the inlier gate *and* :data:`RESIDUAL_RATIO` times the zoom
model's (both 2-D, the zoom model has one parameter more): a far scene keeps pure rotation.

Why not a free translation direction (an essential matrix, or a free epipole per pair): for a
scene at nearly one depth, a sideways translation moves every point alike, exactly as a small
pan or tilt does, so a free direction trades against the rotation the axis search needs
(``cv2.findEssentialMat`` + ``cv2.recoverPose`` on the simulated 720p drive, seed 0: epipolar
residuals of 0.1–0.3 px with rotations 5–22 px from the rotation-only fit's and translation
directions up to 70° off the direction of travel). Fixing the focus of expansion at the
principal point removes that freedom; a heading ``Δe`` px off the optical axis biases a pair's
rotation by about ``s · Δe`` px (0.0125 · 100 px = 1.25 px on that drive), small beside the
rotations the search scores. The continuous fit models the translation properly afterwards
(:mod:`calib.natural_motion`). Either way the images alone measure the rotation: a wrong gyro
still predicts it badly and is refused by :func:`calib.axes.check_axes`.
"""

from __future__ import annotations

import numpy as np

from calib.axes import fit_rotation

#: Rotation-only median residual / zoom-model median residual above which a pair is
#: translating.
RESIDUAL_RATIO = 1.5
#: Rotation-only median residual, as a fraction of the inlier gate, below which a pair is
#: never called translating (0.5 px of the 2 px gate of :func:`calib.axes.rotations_from_pairs`).
MIN_RESIDUAL_FRACTION = 0.25
#: Zoom scan: coarse range and step, then a fine step around the coarse best.
ZOOM_RANGE = 0.08
ZOOM_COARSE = 0.005
ZOOM_FINE = 0.0005


def zoomed(a: np.ndarray, s: float) -> np.ndarray:
    """Unit bearings ``a (N, 3)`` (in front of the camera) zoomed by ``1 + s`` about the
    optical axis."""
    x = a[:, :2] / a[:, 2:] * (1.0 + s)
    out = np.concatenate([x, np.ones((a.shape[0], 1))], axis=1)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _median_residual(a: np.ndarray, b: np.ndarray, R: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(a @ R.T - b, axis=1)))


def fit_rotation_zoom(
    a: np.ndarray, b: np.ndarray, threshold_rad: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Rotation, inlier mask, zoom ``s`` and median residual (rad) of the zoom model."""

    def at(s: float) -> tuple[float, np.ndarray, np.ndarray]:
        az = zoomed(a, s)
        R, inl = fit_rotation(az, b, threshold_rad, seed=seed)
        return _median_residual(az, b, R), R, inl

    coarse = np.arange(-ZOOM_RANGE, ZOOM_RANGE + ZOOM_COARSE / 2, ZOOM_COARSE)
    s0 = float(coarse[int(np.argmin([at(float(s))[0] for s in coarse]))])
    fine = s0 + np.arange(-ZOOM_COARSE, ZOOM_COARSE + ZOOM_FINE / 2, ZOOM_FINE)
    fits = [at(float(s)) for s in fine]
    k = int(np.argmin([f[0] for f in fits]))
    r, R, inl = fits[k]
    return R, inl, float(fine[k]), r


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
    R, inl, _, r_zoom = fit_rotation_zoom(a, b, threshold_rad, seed)
    if r_rot <= RESIDUAL_RATIO * r_zoom:
        return R0, inl0, False
    return R, inl, True
