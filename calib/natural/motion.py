"""Camera translation as a nuisance of natural-scene calibration ("driving" scenes).

Filmed from a moving vehicle, or with near objects, a scene point does not move between two
frames by the camera's rotation alone: with the camera translating by ``t`` and the point at
inverse depth ``ρ``, its image lies on the *epipolar line* through the rotation-predicted
point ``p̂'`` and the *epipole* ``e ~ K t`` (the focus of expansion of forward motion), at a
distance along the line set by ``ρ``. Eliminating the unknown ``ρ`` of every point leaves one
residual per track, the distance of ``p̂'`` from the line through the observed ``p'`` and
``e``::

    r = (ẽ · (p̃̂' × p̃')) / ‖(p̃' × ẽ)₁₂‖          (homogeneous pixels, ẽ may lie at infinity)

Per frame pair the epipole is a nuisance chosen by the data: for given parameters the ``ẽ``
minimising the pair's ``Σ r²`` is the smallest eigenvector of ``Σ w m mᵀ`` with
``m = p̃̂' × p̃'`` and ``w = 1 / ‖(p̃' × ẽ)₁₂‖²`` (iterated). :func:`fit_translation` fits the
calibration parameters to these residuals by robust Levenberg–Marquardt (variable projection:
the epipoles are re-estimated at every step; finite-difference Jacobian of the numpy residual
of :class:`calib.problem.ResidualModel`, the same rotation model as the rotation-only fit).

Which model a session needs is decided by the data (:func:`prefers_translation`): under pure
rotation the rotation-only fit's mean squared 2-D track error is about twice the epipolar
one's (two coordinates against one); a translating camera's parallax makes it much larger.
(The epipolar side of this test uses the ``travel`` model: free per-pair epipoles would also
absorb part of any rotation misfit.)

Two nuisance models: ``per-pair``, a free epipole per frame pair (the most general, but for
a plane at nearly constant depth a shift of the epipole moves every point alike, exactly
like an error of the pair's rotation: the time offset and bias are then poorly determined),
and ``travel``, one direction of travel per :data:`SEGMENT_S` of video in the world frame,
carried into each pair's camera frame by the gyro's own orientation (a vehicle's velocity
keeps its direction while the camera shakes; what ``auto`` fits).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calib.data import StreakSet
from calib.errors import CalibError
from calib.params import THETA_NAMES, bounded_step
from calib.problem import ResidualModel

if TYPE_CHECKING:
    pass

#: ``--translation`` choices.
TRANSLATIONS = ("none", "auto", "per-pair", "travel")
#: Under pure rotation the ratio of mean squared 2-D to (``travel``) epipolar residuals is
#: about 2 for isotropic noise (3.4–3.6 measured on simulated far scenes of 1–10 s: tracking
#: noise is larger along the blur); a car at 3 m/s filming a plane 8 m away gives 13.5.
#: ``auto`` models translation above this.
AUTO_RATIO = 6.0
#: What ``auto`` fits when the data show translation.
AUTO_MODEL = "travel"
#: Fewest tracks of a frame pair whose epipole is estimated (others are dropped).
MIN_PAIR_TRACKS = 8
#: Outliers: residuals beyond this many robust sigmas get no weight.
OUTLIER_SIGMAS = 5.0
#: ``travel``: one direction of travel (world frame) per this many seconds of video.
SEGMENT_S = 1.0
#: Finite-difference steps by parameter name prefix.
FD_STEP = {"timeshift_s": 1e-5, "readout_s": 1e-5, "bias": 1e-5, "rot": 1e-5, "scale": 1e-5}


def _homog(p: np.ndarray, c: np.ndarray, f: float) -> np.ndarray:
    """Conditioned homogeneous pixels ``((x − c) / f, 1)`` ``(N, 3)``."""
    return np.column_stack([(p - c) / f, np.ones(len(p))])


def epipoles(
    pred: np.ndarray,
    obs: np.ndarray,
    group: np.ndarray,
    centre: np.ndarray,
    f: float,
    weight: np.ndarray | None = None,
    maps: np.ndarray | None = None,
    rounds: int = 3,
) -> np.ndarray:
    """Least-squares epipole directions ``(G, 3)`` (unit) of tracks ``pred -> obs`` grouped
    by ``group (N,)`` in ``0..G-1`` (see the module docstring): the epipole of track ``i``
    (conditioned coordinates) is ``maps[i] @ d[group[i]]``, with ``maps (N, 3, 3)`` the
    identity when ``None`` (a free epipole per group)."""
    qp, qo = _homog(pred, centre, f), _homog(obs, centre, f)
    m = np.cross(qp, qo)
    w0 = np.ones(len(m)) if weight is None else weight
    n_groups = int(group.max()) + 1 if group.size else 0
    mm = m if maps is None else np.einsum("nji,nj->ni", maps, m)  # e · m = d · (Aᵀ m)
    D = np.zeros((n_groups, 3))
    D[:, 2] = 1.0
    for k in range(n_groups):
        sel = np.flatnonzero((group == k) & (w0 > 0))
        if sel.size < 3:
            continue
        d = np.array([0.0, 0.0, 1.0])
        for r in range(rounds):
            w = w0[sel].copy()
            if r:
                e = d[None, :] if maps is None else np.einsum("nij,j->ni", maps[sel], d)
                l12 = np.cross(qo[sel], e)[:, :2]
                w = w / np.maximum(np.sum(l12**2, axis=1), 1e-6)
            A = (mm[sel] * w[:, None]).T @ mm[sel]
            d = np.linalg.eigh(A)[1][:, 0]
        D[k] = d
    return D


def camera_orientations(
    model: ResidualModel, theta: np.ndarray, t_cam_s: np.ndarray, substeps: int = 8
) -> np.ndarray:
    """``(M, 3, 3)`` camera orientations (camera to the first time's camera frame) at sorted
    camera times, integrated from the gyro under ``theta`` (offset, bias, mounting, scale)."""
    from blurtrack.geometry.rotation import so3_exp
    from calib.params import LAYOUT, scale_matrix

    R = so3_exp(theta[LAYOUT["rotation"]]) @ model.R0_cam_imu
    Sinv = np.linalg.inv(scale_matrix(theta))
    t = np.asarray(t_cam_s, float)
    edges = t[:-1, None] + (t[1:] - t[:-1])[:, None] * (np.arange(substeps) + 0.5) / substeps
    mid = edges.reshape(-1) + theta[LAYOUT["timeshift_s"]]
    w = np.stack(model.gyro.omega_components(mid), axis=1) - theta[LAYOUT["bias"]]
    h = np.repeat((t[1:] - t[:-1]) / substeps, substeps)
    steps = so3_exp((w @ (R @ Sinv).T) * h[:, None])
    out = np.empty((t.size, 3, 3))
    out[0] = np.eye(3)
    cur = np.eye(3)
    for k in range(t.size - 1):
        for j in range(substeps):
            cur = cur @ steps[k * substeps + j]
        out[k + 1] = cur
    return out


def epipolar_residual(
    pred: np.ndarray, obs: np.ndarray, e_rows: np.ndarray, centre: np.ndarray, f: float
) -> np.ndarray:
    """``(N,)`` distance (px) of ``pred`` from the line through ``obs`` and its epipole."""
    qp, qo = _homog(pred, centre, f), _homog(obs, centre, f)
    l = np.cross(qo, e_rows)
    n = np.maximum(np.linalg.norm(l[:, :2], axis=1), 1e-9)
    return np.einsum("ij,ij->i", l, qp) / n * f


@dataclass(frozen=True)
class TranslationFit:
    """The calibration fitted with a per-pair translation nuisance.

    ``theta``: all parameters; ``sigma``: the fitted ones (Gauss–Newton, residual variance
    with the epipoles' and depths' degrees of freedom removed); ``epipoles``: per frame pair
    (conditioned homogeneous, unit); ``inlier``: per track; ``rms_px``: epipolar inliers.
    """

    theta: np.ndarray
    sigma: dict[str, float]
    epipoles: np.ndarray
    inlier: np.ndarray
    rms_px: float
    iterations: int
    converged: bool
    residual_px: np.ndarray
    #: Median |epipolar residual| (px) of the usable tracks: compares fits.
    cost: float


class MotionProblem:
    def __init__(
        self,
        model: ResidualModel,
        streaks: StreakSet,
        centre: np.ndarray,
        f: float,
        travel: bool = False,
    ) -> None:
        self.model, self.streaks, self.centre, self.f = model, streaks, centre, f
        frames, first, self.pair = np.unique(streaks.frame, return_index=True, return_inverse=True)
        self.n_pairs = int(frames.size)
        counts = np.bincount(self.pair, minlength=self.n_pairs)
        self.usable = counts[self.pair] >= MIN_PAIR_TRACKS
        self.travel = travel
        # each pair's later frame, dated at its exposure midpoint (row 0)
        self.t_b = streaks.frame_t_s[first] + streaks.exposure_s[first]
        seg = np.floor((self.t_b - self.t_b[0]) / SEGMENT_S).astype(np.int64)
        self.group = seg[self.pair] if travel else self.pair
        self.row_b = streaks.rows[:, 1] / model.height

    def maps(self, theta: np.ndarray) -> np.ndarray | None:
        """``travel``: per track, travel direction (first frame's camera axes) -> conditioned
        epipole at the time its later point was seen (the pair's orientation from the gyro,
        carried to the track's own row by the rate there)."""
        if not self.travel:
            return None
        from blurtrack.geometry.rotation import so3_exp
        from calib.params import LAYOUT, scale_matrix

        fx, fy, cx, cy = theta[LAYOUT["intrinsics"]]
        ro = float(theta[LAYOUT["readout_s"]])
        Rw = camera_orientations(self.model, theta, self.t_b + ro / 2)
        t_i = self.t_b[self.pair] + ro * self.row_b
        R = so3_exp(theta[LAYOUT["rotation"]]) @ self.model.R0_cam_imu
        w = np.stack(self.model.gyro.omega_components(t_i + theta[LAYOUT["timeshift_s"]]), 1)
        w_cam = (w - theta[LAYOUT["bias"]]) @ (R @ np.linalg.inv(scale_matrix(theta))).T
        dt = t_i - (self.t_b[self.pair] + ro / 2)
        local = so3_exp(-w_cam * dt[:, None])  # R_w(t_i)ᵀ = exp(−ω δt) R_pairᵀ
        K = np.array(
            [[fx / self.f, 0, (cx - self.centre[0]) / self.f],
             [0, fy / self.f, (cy - self.centre[1]) / self.f], [0, 0, 1.0]]
        )  # fmt: skip
        return K @ local @ np.transpose(Rw, (0, 2, 1))[self.pair]

    def predicted(self, theta: np.ndarray) -> np.ndarray:
        return self.model.residual_np(theta, self.streaks) + self.streaks.end

    def epipoles(self, theta: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """Per pair epipoles (free), or per segment travel directions ``(G, 3)``."""
        return epipoles(
            self.predicted(theta), self.streaks.end, self.group, self.centre, self.f,
            weight * self.usable, self.maps(theta),
        )  # fmt: skip

    def residual(self, theta: np.ndarray, E: np.ndarray) -> np.ndarray:
        maps = self.maps(theta)
        d = E[self.group]
        Ep = d if maps is None else np.einsum("nij,nj->ni", maps, d)
        return epipolar_residual(self.predicted(theta), self.streaks.end, Ep, self.centre, self.f)


def cauchy_weights(r: np.ndarray, usable: np.ndarray) -> tuple[np.ndarray, float]:
    """Robust weights (Cauchy, outliers zero) and the robust sigma of ``r``."""
    a = np.abs(r[usable])
    s = max(1.4826 * float(np.median(a)) if a.size else 1.0, 1e-6)
    w = 1.0 / (1.0 + (r / (2.0 * s)) ** 2)
    w[(np.abs(r) > OUTLIER_SIGMAS * s) | ~usable] = 0.0
    return w, s


def _step(name: str, theta: np.ndarray, i: int) -> float:
    for k, v in FD_STEP.items():
        if name.startswith(k):
            return v
    return 1e-4 * max(1.0, abs(float(theta[i])))  # intrinsics, px


def fit_translation(
    model: ResidualModel,
    streaks: StreakSet,
    theta0: np.ndarray,
    fit_idx: tuple[int, ...],
    centre: np.ndarray,
    f: float,
    max_iter: int = 40,
    travel: bool = False,
) -> TranslationFit:
    """Robust LM of the epipolar residuals over ``theta[fit_idx]`` from ``theta0``; with
    ``travel`` the epipoles follow the gyro from one direction of travel per segment."""
    pb = MotionProblem(model, streaks, np.asarray(centre, float), float(f), travel)
    if np.count_nonzero(pb.usable) < 2 * len(fit_idx) + 3 * pb.n_pairs:
        raise CalibError(
            "too few feature tracks to model the camera's translation: "
            f"{int(np.count_nonzero(pb.usable))} in pairs of >= {MIN_PAIR_TRACKS}"
        )
    theta = np.asarray(theta0, float).copy()
    w = pb.usable.astype(float)
    E = pb.epipoles(theta, w)
    r = pb.residual(theta, E)
    w, _ = cauchy_weights(r, pb.usable)
    lam, iterations, converged = 1e-3, 0, False
    names = [THETA_NAMES[i] for i in fit_idx]
    J = np.zeros((len(r), len(fit_idx)))
    for it in range(1, max_iter + 1):
        iterations = it
        cost = float(np.sum(w * r**2))
        for j, i in enumerate(fit_idx):
            h = _step(names[j], theta, i)
            tp = theta.copy()
            tp[i] += h
            J[:, j] = (pb.residual(tp, E) - r) / h
        sw = np.sqrt(w)
        Jw, rw = J * sw[:, None], r * sw
        A, g = Jw.T @ Jw, Jw.T @ rw
        D = np.diag(np.maximum(np.diag(A), 1e-12))
        accepted = False
        for _ in range(10):
            try:
                dx = -np.linalg.solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            tn = theta.copy()
            tn[list(fit_idx)] += dx
            tb = bounded_step(tn)
            if tb is None:
                lam *= 10
                continue
            En = pb.epipoles(tb, w)
            rn = pb.residual(tb, En)
            if float(np.sum(w * rn**2)) < cost:
                theta, E, r, accepted = tb, En, rn, True
                lam = max(lam / 3, 1e-9)
                break
            lam *= 10
        if not accepted:
            converged = True
            break
        w, _ = cauchy_weights(r, pb.usable)
        if np.all(np.abs(dx) <= 1e-6 * np.sqrt(np.diag(np.linalg.pinv(A)) + 1e-30) + 1e-12):
            converged = True
            break
        if float(np.sum(w * r**2)) > cost * (1 - 1e-7):
            converged = True
            break
    inl = w > 0
    n_in = int(np.count_nonzero(inl))
    dof = max(n_in - len(fit_idx) - 2 * len(E), 1)
    s2 = float(np.sum(w * r**2)) / dof
    sw = np.sqrt(w)
    cov = np.linalg.pinv((J * sw[:, None]).T @ (J * sw[:, None])) * s2
    sigma = {n: float(np.sqrt(max(cov[j, j], 0.0))) for j, n in enumerate(names)}
    rms = float(np.sqrt(np.mean(r[inl] ** 2))) if n_in else float("nan")
    cost = float(np.median(np.abs(r[pb.usable])))
    return TranslationFit(theta, sigma, E, inl, rms, iterations, converged, r, cost)


def mean_squares(
    model: ResidualModel,
    streaks: StreakSet,
    theta: np.ndarray,
    centre: np.ndarray,
    f: float,
    travel: bool = True,
) -> tuple[float, float]:
    """Trimmed mean squared 2-D track error (rotation only) and epipolar residual (px²) at
    ``theta`` (tracks beyond the 95th percentile of either are left out of both). The
    epipolar side uses the ``travel`` model by default: free per-pair epipoles also absorb
    part of any rotation misfit (an unfitted gyro scale error), which raised the ratio of a
    far scene to 7 over 10 s of video."""
    pb = MotionProblem(model, streaks, np.asarray(centre, float), float(f), travel)
    r2 = np.sum(model.residual_np(theta, streaks) ** 2, axis=1)
    E = pb.epipoles(theta, pb.usable.astype(float))
    re = pb.residual(theta, E) ** 2
    keep = pb.usable & (r2 <= np.percentile(r2, 95)) & (re <= np.percentile(re, 95))
    if not np.any(keep):
        return float("nan"), float("nan")
    return float(np.mean(r2[keep])), float(np.mean(re[keep]))


def prefers_translation(ms_rotation: float, ms_epipolar: float) -> bool:
    """``auto``: whether the parallax the rotation model leaves is more than its missing
    coordinate explains (see the module docstring)."""
    return bool(ms_rotation > AUTO_RATIO * max(ms_epipolar, 1e-12))
