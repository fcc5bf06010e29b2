"""Fast residuals and exact-in-form Jacobians from orientation integrated once on a fixed grid.

The residual of a streak or track warps a point ``m`` from ``t_a`` to ``t_b`` (camera clock)
with the relative camera rotation ``R_ci Q R_ciᵀ``, where ``Q = Φ(τ_a)ᵀ Φ(τ_b)`` is the
relative rotation of the *corrected* gyro frame, ``τ = t + shift`` (IMU clock) and
``dΦ/dτ = Φ [ω(τ)]×`` with ``ω = A ω_meas + c``, ``A = (I + S)⁻¹`` (exact inverse),
``c = −A b``. Only ``A`` and ``c`` enter the integration, so once per evaluation:

1. ``Φ`` on a grid of fixed IMU-clock nodes ``t_k = k h`` (:data:`GRID_STEP_S`, independent of
   the gyro's rate): each cell's step is ``exp(ω(t_k + h/2) h)`` (the midpoint rule of
   :func:`blurtrack.geometry.kernels.relative_rotation`), composed by a parallel prefix scan
   (cumulative products in ``log2`` passes);
2. ``Φ(τ)`` at any time by the partial cell's own midpoint step,
   ``Φ(τ) = Φ_k exp(ω((t_k + τ)/2) (τ − t_k))`` (continuous across nodes, second order);
3. for Jacobians, the cumulative integrals ``∫Φ`` (9 channels) and ``∫Φ[:, i] ω_meas,j``
   (27): a perturbation ``δω = δA ω_meas + δc`` moves ``Q`` to ``Q exp([δφ]×)`` with
   ``δφ = Φ(τ_b)ᵀ ∫_{τ_a}^{τ_b} Φ δω dτ`` (first order), and the end times move it by
   ``ω(τ_b) δτ_b − Qᵀ ω(τ_a) δτ_a``.

The cost of an evaluation is linear in the number of residuals plus one pass over the grid
(the recording's duration over ``h``), whatever the gyro rate. The Jacobian is CasADi's
``ca.jacobian`` of one small scalar SX function per residual (``Function.map`` over all):
``Q(θ) = Q_c exp([δφ(θ)]×)`` with ``δφ`` linear in ``(A(θ) − A_c, c(θ) − c_c, δτ_a, δτ_b)``
and the grid's integrals as data, then the camera rotation, unprojection and projection of
:mod:`blurtrack.geometry.kernels`. Its value at the current ``θ_c`` is the numpy residual, and
its first derivatives are exact up to the grid's quadrature.
"""

from __future__ import annotations

from typing import Any, cast

import casadi as ca
import numpy as np

from blurtrack.geometry.gyro import GyroTrace
from blurtrack.geometry.kernels import (
    NUMPY_OPS,
    Mat3,
    constant_mat3,
    matmul3,
    matvec3,
    project_c,
    so3_exp_c,
    transpose3,
    unproject_c,
)
from calib import gridops
from calib.data import StreakSet
from calib.gridops import eye_plus_hat, left_jacobian, mat3, prefix_products
from calib.params import LAYOUT, N_THETA, SCALE_ENTRIES, inverse3, scale_tuple
from calib.problem import CA_OPS

#: Grid step (s) of the orientation integration: half the 1 ms sub-step of the per-streak
#: model, fixed in IMU time (nodes at multiples of it), whatever the gyro's rate.
GRID_STEP_S = 5e-4
#: Margin (s) of a grid beyond the times it was built for (:meth:`GridEvaluator._grid`).
GRID_PAD_S = 0.15
#: Data of one warped point (see :meth:`GridEvaluator._block`).
N_BLOCK = 9 + 27 + 9 + 3 + 3
#: Per-residual data columns of the SX Jacobian (see :meth:`GridEvaluator._data`).
N_DATA = 6 + N_BLOCK
#: Inputs ``z = (δφ, δ, K)`` of the chain-rule Jacobian (:meth:`GridEvaluator.evaluate`).
N_Z = 10


class GridEvaluator:
    """Residuals ``(N, 2)`` and Jacobians ``(N, 2, N_THETA)`` of streak sets (endpoint form
    of :func:`calib.problem.endpoint_residual`, any ``StreakSet``, tracks included) by the
    grid integration of the module docstring (``residual``, ``evaluate``, ``n_residuals``:
    :class:`calib.solve.Evaluator`)."""

    #: Residual values and SX data columns per residual (a subclass may add more).
    n_residuals = 2
    n_data = N_DATA

    def __init__(
        self,
        gyro: GyroTrace,
        R0_cam_imu: np.ndarray,
        dist: tuple[float, ...],
        height: int,
        step_s: float = GRID_STEP_S,
    ) -> None:
        self.gyro = gyro
        self.R0_cam_imu = np.asarray(R0_cam_imu, float)
        self.dist = tuple(dist)
        self.height = int(height)
        self.h = float(step_s)
        self._th = ca.SX.sym("theta", N_THETA)
        self._thc = ca.SX.sym("theta_c", N_THETA)
        self._d = ca.SX.sym("d", self.n_data)
        self._r: ca.SX | None = None  # built when first needed (:meth:`_map`)
        self._maps: dict[tuple[int, ...], ca.Function] = {}
        self._zmap: ca.Function | None = None
        self._last_grid: dict[str, Any] | None = None

    # ------------------------------------------------------------------ grid
    def _omega(
        self, t_imu: np.ndarray, A: np.ndarray, c: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Corrected rate ``A ω_meas(t) + c`` ``(…, 3)`` and the measured rate ``(…, 3)``."""
        w = self.gyro.omega_at(t_imu.reshape(-1)).reshape(*t_imu.shape, 3)
        wc = np.empty_like(w)
        for r in range(3):  # by components: numpy's matmul with a 3-wide inner loop is 15x slower
            wc[..., r] = w[..., 0] * A[r, 0] + w[..., 1] * A[r, 1] + w[..., 2] * A[r, 2] + c[r]
        return wc, w

    def _grid(self, theta: np.ndarray, tau: np.ndarray, integrals: bool) -> dict[str, Any]:
        """``Φ`` on the nodes covering ``τ`` (and the integrals), for the gyro correction of
        ``theta``. The last grid is kept: it only depends on ``A``, ``c`` (scale and bias),
        so evaluations that change the other parameters (the shift and focal search, a
        coarse stage without bias and scale) reuse it while it covers their times (it is
        built :data:`GRID_PAD_S` wider on both sides)."""
        A = np.array(inverse3(scale_tuple(theta))).reshape(3, 3)
        c = -A @ theta[LAYOUT["bias"]]
        h = self.h
        k_lo = int(np.floor(np.min(tau) / h)) - 1
        k_hi = int(np.ceil(np.max(tau) / h)) + 1
        last = self._last_grid
        if (
            last is not None
            and np.array_equal(last["A"], A)
            and np.array_equal(last["c"], c)
            and (integrals <= ("cum" in last))
            and last["k_lo"] <= k_lo
            and k_hi <= last["k_lo"] + last["phi"].shape[1] - 1
        ):
            return last
        pad = int(np.ceil(GRID_PAD_S / h))
        k_lo, k_hi = k_lo - pad, k_hi + pad
        nodes = np.arange(k_lo, k_hi + 1) * h
        w_mid, wm_mid = self._omega(nodes[:-1] + h / 2, A, c)
        wx, wy, wz = w_mid.T * h
        steps = np.stack(so3_exp_c(wx, wy, wz, NUMPY_OPS))
        phi = prefix_products(steps)  # (9, M + 1)
        out: dict[str, Any] = {"A": A, "c": c, "k_lo": k_lo, "phi": phi, "nodes": nodes}
        if integrals:
            ph_mid = (phi[:, :-1] + phi[:, 1:]) * (h / 2)  # (9, M) cell integrals of Φ
            cols = ph_mid.reshape(3, 3, -1)  # [row r, column i, cell]
            ca_cells = cols[:, :, None, :] * wm_mid.T[None, None, :, :]  # (r, i, j, cell)
            cells = np.concatenate([ph_mid, ca_cells.reshape(27, -1)], axis=0)  # (36, M)
            # Node-major (M + 1, 36): a look-up gathers contiguous rows.
            cum = np.zeros((cells.shape[1] + 1, 36))
            np.cumsum(cells.T, axis=0, out=cum[1:])
            out["cum"] = cum
        self._last_grid = out
        return out

    def _at(self, grid: dict[str, Any], tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Φ(τ)`` ``(9, N)`` and the corrected rate at ``τ`` ``(N, 3)``."""
        h, k_lo, phi = self.h, grid["k_lo"], grid["phi"]
        k = np.floor(tau / h).astype(np.int64)
        t_k = k * h
        dt = tau - t_k
        w_half, _ = self._omega((t_k + tau) / 2, grid["A"], grid["c"])
        wx, wy, wz = w_half.T * dt
        part = so3_exp_c(wx, wy, wz, NUMPY_OPS)
        P = np.stack(matmul3(mat3(phi[:, k - k_lo]), part))
        w_end, _ = self._omega(tau, grid["A"], grid["c"])
        return P, w_end

    def _cum_at(self, grid: dict[str, Any], tau: np.ndarray) -> np.ndarray:
        """Cumulative integrals ``(36, N)`` at ``τ`` (linear within a cell)."""
        pos = tau / self.h - grid["k_lo"]
        i = np.floor(pos).astype(np.int64)
        f = pos - i
        cum = grid["cum"]
        lo, out = cum[i], cum[i + 1]
        out -= lo  # in place: these are (N, 36) arrays, allocation dominates
        out *= f[:, None]
        out += lo
        return out.T

    def _times(self, theta: np.ndarray, streaks: StreakSet) -> tuple[np.ndarray, np.ndarray]:
        rows = streaks.rows / self.height
        ro, sh = theta[LAYOUT["readout_s"]], theta[LAYOUT["timeshift_s"]]
        tau_a = streaks.frame_t_s + ro * rows[:, 0] + sh
        tau_b = streaks.frame_t_s + ro * rows[:, 1] + streaks.exposure_s + sh
        return tau_a, tau_b

    # -------------------------------------------------------------- residual
    def _project(self, theta: np.ndarray, x: np.ndarray, y: np.ndarray, Q: tuple):
        """Points ``(x, y)`` carried by the relative gyro-frame rotation ``Q`` (9-tuple)."""
        wx, wy, wz = theta[LAYOUT["rotation"]]
        R = matmul3(so3_exp_c(wx, wy, wz, NUMPY_OPS), constant_mat3(self.R0_cam_imu))
        R_cam = matmul3(matmul3(R, Q), transpose3(R))
        K = tuple(theta[LAYOUT["intrinsics"]])
        ray = unproject_c(x, y, K, self.dist)
        X, Y, Z = matvec3(transpose3(R_cam), ray)
        return project_c(X, Y, Z, K, self.dist)

    def _warp(self, theta: np.ndarray, streaks: StreakSet, Q: tuple) -> np.ndarray:
        u, v = self._project(theta, streaks.start[:, 0], streaks.start[:, 1], Q)
        return np.stack([u - streaks.end[:, 0], v - streaks.end[:, 1]], axis=1)

    def _relative(self, theta: np.ndarray, streaks: StreakSet, integrals: bool):
        theta = np.asarray(theta, float)
        tau_a, tau_b = self._times(theta, streaks)
        grid = self._grid(theta, np.concatenate([tau_a, tau_b]), integrals)
        Pa, wa = self._at(grid, tau_a)
        Pb, wb = self._at(grid, tau_b)
        Q = np.stack(matmul3(transpose3(mat3(Pa)), mat3(Pb)))
        return grid, tau_a, tau_b, Pb, Q, wa, wb

    def residual(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """Residuals ``(N, 2)`` (px)."""
        if len(streaks) == 0:
            return np.zeros((0, 2))
        _, _, _, _, Q, _, _ = self._relative(theta, streaks, False)
        return self._warp(np.asarray(theta, float), streaks, mat3(Q))

    # -------------------------------------------------------------- jacobian
    def _sx_common(self) -> dict[str, Any]:
        """Terms of the SX residual shared by every warped point of a residual."""
        th, thc = self._th, self._thc
        L = LAYOUT

        def affine(t: ca.SX) -> tuple[tuple, list]:
            A = inverse3(scale_tuple(t))
            b = [t[i] for i in range(L["bias"].start, L["bias"].stop)]
            c = [-(A[3 * r] * b[0] + A[3 * r + 1] * b[1] + A[3 * r + 2] * b[2]) for r in range(3)]
            return A, c

        A, c = affine(th)
        Ac, cc = affine(thc)
        i_sh, i_ro = L["timeshift_s"], L["readout_s"]
        rot = L["rotation"]
        R = matmul3(
            so3_exp_c(th[rot.start], th[rot.start + 1], th[rot.start + 2], CA_OPS),
            constant_mat3(self.R0_cam_imu),
        )
        return {
            "dA": [A[k] - Ac[k] for k in range(9)],
            "dc": [c[k] - cc[k] for k in range(3)],
            "d_sh": th[i_sh] - thc[i_sh],
            "d_ro": th[i_ro] - thc[i_ro],
            "R": R,
            "K": tuple(th[i] for i in range(L["intrinsics"].start, L["intrinsics"].stop)),
        }

    def _warp_sx(
        self, cm: dict[str, Any], sx: Any, sy: Any, ya: Any, yk: Any, blk: list
    ) -> tuple[Any, Any]:
        """The start ``(sx, sy)`` (row ``ya``) warped to a point of row time ``yk`` whose
        :data:`N_BLOCK` data ``blk`` are :meth:`_block`'s: ``Q_c``, ``∂δφ/∂A``, ``∂δφ/∂c``,
        ``ω(τ_k)``, ``Q_cᵀ ω(τ_a)``."""
        Qc = cast(Mat3, tuple(blk[i] for i in range(9)))
        GA = [[blk[9 + 9 * r + k] for k in range(9)] for r in range(3)]  # δφ_r / δA_(i,j)
        Gc = [[blk[36 + 3 * r + k] for k in range(3)] for r in range(3)]
        wk = [blk[45 + r] for r in range(3)]
        qwa = [blk[48 + r] for r in range(3)]
        dta, dtk = cm["d_sh"] + cm["d_ro"] * ya, cm["d_sh"] + cm["d_ro"] * yk
        phi = [
            sum(GA[r][k] * cm["dA"][k] for k in range(9))
            + sum(Gc[r][k] * cm["dc"][k] for k in range(3))
            + wk[r] * dtk
            - qwa[r] * dta
            for r in range(3)
        ]
        Q = matmul3(Qc, so3_exp_c(phi[0], phi[1], phi[2], CA_OPS))
        R = cm["R"]
        R_cam = matmul3(matmul3(R, Q), transpose3(R))
        ray = unproject_c(sx, sy, cm["K"], self.dist)
        X, Y, Z = matvec3(transpose3(R_cam), ray)
        return project_c(X, Y, Z, cm["K"], self.dist)

    def _residual_sx(self) -> ca.SX:
        """The endpoint residual of one streak / track (data layout of :meth:`_data`)."""
        d = self._d
        sx, sy, ex, ey, ya, yb = (d[i] for i in range(6))
        u, v = self._warp_sx(self._sx_common(), sx, sy, ya, yb, [d[6 + i] for i in range(N_BLOCK)])
        return ca.vertcat(u - ex, v - ey)

    def _map(self, free: tuple[int, ...]) -> ca.Function:
        """The SX function of every parameter's Jacobian over ``free`` (:meth:`_residual_sx`),
        mapped over :data:`calib.gridops.MAP_CHUNK` residuals, built once per free set (CasADi's
        ``Function.map`` costs about 16 µs per mapped residual to build: over every residual
        of a fit it cost more than an evaluation, and a new track count rebuilt it)."""
        if free not in self._maps:
            if self._r is None:
                self._r = self._residual_sx()
            J = ca.densify(ca.jacobian(self._r, ca.vertcat(*[self._th[i] for i in free])))
            f = ca.Function("calib_grid_jac", [self._th, self._thc, self._d], [self._r, J])
            # theta and theta_c are shared by every residual (not repeated).
            self._maps[free] = f.map("calib_grid_jac_map", "serial", gridops.MAP_CHUNK, [0, 1], [])
        return self._maps[free]

    def _block(
        self,
        grid: dict[str, Any],
        tau_a: np.ndarray,
        Pa: np.ndarray,
        wa: np.ndarray,
        tau_k: np.ndarray,
    ) -> np.ndarray:
        """``(N_BLOCK, N)`` data of a point warped from ``τ_a`` to ``τ_k`` (:meth:`_warp_sx`):
        ``Q_c``, ``∂δφ/∂A``, ``∂δφ/∂c``, ``ω(τ_k)``, ``Q_cᵀ ω(τ_a)``."""
        Pk, wk = self._at(grid, tau_k)
        Q = np.stack(matmul3(transpose3(mat3(Pa)), mat3(Pk)))
        dcum = self._cum_at(grid, tau_k)
        dcum -= self._cum_at(grid, tau_a)  # (36, N)
        PkT = Pk.reshape(3, 3, -1)  # [row, col, n]: δφ = Φ_kᵀ ∫ …
        I_phi = dcum[:9].reshape(3, 3, -1)  # [row r, col i]
        I_A = dcum[9:].reshape(3, 3, 3, -1)  # [row r, col i, j]
        # δφ_s = Σ_r Φ_k[r, s] ∫ (Φ δω)_r,  (Φ δω)_r = Σ_ij Φ[r, i] (δA_ij ω_j + δc_i δ_ij)
        Gc = np.einsum("rsn,rin->sin", PkT, I_phi).reshape(9, -1)
        GA = np.einsum("rsn,rijn->sijn", PkT, I_A).reshape(27, -1)
        qwa = np.einsum("arn,na->rn", Q.reshape(3, 3, -1), wa)
        return np.concatenate([Q, GA, Gc, wk.T, qwa], axis=0)

    def _data(self, theta: np.ndarray, streaks: StreakSet) -> np.ndarray:
        """``(N_DATA, N)``: points, normalised rows, then the end's :meth:`_block`."""
        theta = np.asarray(theta, float)
        tau_a, tau_b = self._times(theta, streaks)
        grid = self._grid(theta, np.concatenate([tau_a, tau_b]), True)
        Pa, wa = self._at(grid, tau_a)
        rows = streaks.rows / self.height
        head = [streaks.start.T, streaks.end.T, rows.T]
        return np.concatenate([*head, self._block(grid, tau_a, Pa, wa, tau_b)], axis=0)

    def _evaluate_full(
        self, theta: np.ndarray, streaks: StreakSet, free: tuple[int, ...]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and Jacobian by the SX function of every parameter
        (:meth:`_residual_sx`, data :meth:`_data`): the form a subclass with more residuals
        per streak uses."""
        theta = np.asarray(theta, float)
        n, p, k = len(streaks), len(free), self.n_residuals
        th = np.ascontiguousarray(theta)
        r, J = gridops.run_mapped(
            self._map(tuple(free)), [th, th], self._data(theta, streaks).T, k, p
        )
        full = np.zeros((n, k, N_THETA))
        full[:, :, list(free)] = J.reshape(n, p, k).transpose(0, 2, 1)
        return r, full

    def _dphi(self, theta: np.ndarray, streaks: StreakSet, blk: np.ndarray) -> np.ndarray:
        """``∂δφ/∂θ`` ``(3, N_THETA, N)`` of the end rotation's correction (module docstring):
        linear in ``δA``, ``δc`` and the end times, whose derivatives in θ are the same for
        every residual (``δA = −A δS A``, ``c = −A b``). Wide matrix products per component
        (a tall ``(3N, 9)`` one is 4x slower under multi-threaded BLAS)."""
        n = len(streaks)
        A = np.array(inverse3(scale_tuple(theta))).reshape(3, 3)
        b = theta[LAYOUT["bias"]]
        sc, bi = LAYOUT["scale"], LAYOUT["bias"]
        dA = np.zeros((9, 6))
        dc_s = np.zeros((3, 6))
        for e, (r_, c_) in enumerate(SCALE_ENTRIES):
            dS = np.zeros((3, 3))
            dS[r_, c_] = dS[c_, r_] = 1.0
            dA_e = -A @ dS @ A
            dA[:, e] = dA_e.ravel()
            dc_s[:, e] = -dA_e @ b
        GA = blk[9:36].reshape(3, 9, n)
        Gc = blk[36:45].reshape(3, 3, n)
        out = np.zeros((3, N_THETA, n))
        rows = streaks.rows / self.height
        for s in range(3):
            out[s, sc] = dA.T @ GA[s] + dc_s.T @ Gc[s]
            out[s, bi] = -A.T @ Gc[s]
            wk, qwa = blk[45 + s], blk[48 + s]
            out[s, LAYOUT["timeshift_s"]] = wk - qwa
            out[s, LAYOUT["readout_s"]] = wk * rows[:, 1] - qwa * rows[:, 0]
        return out

    def evaluate(
        self, theta: np.ndarray, streaks: StreakSet, free: tuple[int, ...] = tuple(range(N_THETA))
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(N, 2)`` and Jacobian ``(N, 2, N_THETA)`` (zero columns for fixed
        parameters) at ``theta``.

        By the chain rule through ``z = (δφ, rot, K)``: one small SX function gives ``r`` and
        ``∂r/∂z`` (2 × 10) per residual (:meth:`_z_map`), numpy ``∂δφ/∂θ`` (:meth:`_dphi`);
        the same derivative as CasADi's of the residual in every parameter, 1.8x less SX
        virtual-machine time."""
        theta = np.asarray(theta, float)
        n = len(streaks)
        tau_a, tau_b = self._times(theta, streaks)
        grid = self._grid(theta, np.concatenate([tau_a, tau_b]), True)
        Pa, wa = self._at(grid, tau_a)
        blk = self._block(grid, tau_a, Pa, wa, tau_b)
        rot = theta[LAYOUT["rotation"]]
        wx, wy, wz = (float(x) for x in rot)
        Rc = np.array(so3_exp_c(wx, wy, wz, NUMPY_OPS), dtype=float).reshape(3, 3)
        Rc = Rc @ self.R0_cam_imu
        z = np.concatenate([np.zeros(6), theta[LAYOUT["intrinsics"]]])
        d = np.concatenate([streaks.start.T, streaks.end.T, blk[:9]], axis=0).T
        r, Jz = gridops.run_mapped(self._z_map(), [z, Rc.ravel()], d, 2, N_Z)
        Jz = Jz.reshape(n, N_Z, 2).transpose(2, 1, 0)  # (2, N_Z, N)
        dphi = self._dphi(theta, streaks, blk)
        J = Jz[:, 0, None, :] * dphi[0][None]
        for a in (1, 2):
            J += Jz[:, a, None, :] * dphi[a][None]
        # δ = J_l(rot) δrot: the rotation columns through the left Jacobian.
        Jl = left_jacobian(rot)
        for k, i in enumerate(range(*LAYOUT["rotation"].indices(N_THETA))):
            J[:, i] += Jz[:, 3] * Jl[0, k] + Jz[:, 4] * Jl[1, k] + Jz[:, 5] * Jl[2, k]
        for i, zi in zip(range(*LAYOUT["intrinsics"].indices(N_THETA)), (6, 7, 8, 9), strict=True):
            J[:, i] += Jz[:, zi]
        fixed = [i for i in range(N_THETA) if i not in free]
        J[:, fixed] = 0.0
        return r, np.ascontiguousarray(J.transpose(2, 0, 1))

    def _z_map(self) -> ca.Function:
        """``(z, R_c, d) -> (r, ∂r/∂z)`` of one residual at ``z = (δφ, δ, K)`` with
        ``δφ = δ = 0``: ``Q = Q_c (I + [δφ]×)``, ``R = (I + [δ]×) R_c`` (the exponentials to
        first order: the same value and first derivatives at zero, a third of the SX
        instructions); ``z`` and ``R_c`` shared, ``d = (start, end, Q_c)``; mapped over
        :data:`calib.gridops.MAP_CHUNK` residuals (built once)."""
        if self._zmap is None:
            z, Rc, d = ca.SX.sym("z", N_Z), ca.SX.sym("R_c", 9), ca.SX.sym("d", 13)
            Qc = cast(Mat3, tuple(d[4 + i] for i in range(9)))
            Q = matmul3(Qc, eye_plus_hat(z[0], z[1], z[2]))
            R = matmul3(eye_plus_hat(z[3], z[4], z[5]), cast(Mat3, tuple(Rc[i] for i in range(9))))
            R_cam = matmul3(matmul3(R, Q), transpose3(R))
            K = (z[6], z[7], z[8], z[9])
            X, Y, Zc = matvec3(transpose3(R_cam), unproject_c(d[0], d[1], K, self.dist))
            u, v = project_c(X, Y, Zc, K, self.dist)
            r = ca.vertcat(u - d[2], v - d[3])
            f = ca.Function("calib_grid_z", [z, Rc, d], [r, ca.densify(ca.jacobian(r, z))])
            self._zmap = f.map("calib_grid_z_map", "serial", gridops.MAP_CHUNK, [0, 1], [])
        return self._zmap
