"""Axis discovery on laser midpoints (calib.axes.laser) with known truth, and refusals; its
orientation table, batched prediction and cell look-up against direct computations."""

from __future__ import annotations

from typing import cast

import numpy as np
import pytest

from blurtrack.geometry.gyro import GYRO_UPSAMPLE, GyroTrace
from blurtrack.geometry.kernels import Mat3, relative_rotation
from blurtrack.geometry.rotation import so3_exp, so3_log
from calib.axes.laser import CellIndex, OrientationTable, carried_px, covered, search_axes_laser
from calib.axes.search import (
    check_axes,
    gyro_rotations,
    nearest_axis_permutation,
    proper_axis_permutations,
)
from calib.data import relative_gyro
from calib.errors import AxisSearchError, CalibError
from calib.testing import make_problem
from calib.tracks import mean_rows


@pytest.fixture(scope="module")
def problem():
    return make_problem(
        seed=3, n_frames=10, dots_per_frame=30, endpoint_noise_px=0.05, tracked=True
    )


def _search(p, gyro):
    s = p.streaks
    return search_axes_laser(
        s.mid,
        mean_rows(s),
        s.frame,
        s.frame_t_s,
        s.exposure_s,
        p.initial.camera,
        relative_gyro(gyro, s.t0_s),
        0.0,
        0.06,
    )


def test_laser_search_finds_the_true_axes_and_shift(problem) -> None:
    res = _search(problem, problem.gyro)
    check_axes(res)
    P = proper_axis_permutations()[nearest_axis_permutation(problem.truth.R_cam_imu)]
    assert np.allclose(res.R_cam_imu, P)
    assert res.margin > 5
    # The permutation is not the true (1.5 degrees misaligned) rotation: the shift is an
    # initial value for the fit, a few ms off at most.
    assert abs(res.winner.timeshift_s - problem.truth.timeshift_cam_imu_s) < 3e-3


def test_laser_search_refuses_a_foreign_gyro(problem) -> None:
    other = make_problem(seed=9, n_frames=10, dots_per_frame=30, tracked=True).gyro
    res = _search(problem, GyroTrace(other.t_s, other.omega_radps))
    with pytest.raises(AxisSearchError, match="explains|ambiguous"):
        check_axes(res)


def test_laser_search_says_a_gyro_of_zeros_carries_nothing(problem) -> None:
    g = problem.gyro
    res = _search(problem, GyroTrace(g.t_s, np.zeros_like(g.omega_radps)))
    assert res.motion_px < 1e-9
    # The gyro's prediction is what did not move (the dots did): the message says so.
    with pytest.raises(AxisSearchError, match="the gyro carries the dots by a median 0.00 px"):
        check_axes(res)


def _cumulative(t: np.ndarray, s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Exact ``∫ s`` from ``t[0]`` to ``x`` of the piecewise linear ``s`` (held beyond ends)."""
    F = np.concatenate([[0.0], np.cumsum(np.diff(t) * (s[:-1] + s[1:]) / 2)])
    k = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 1)
    return F[k] + (x - t[k]) * (s[k] + np.interp(x, t, s)) / 2


def test_orientation_table_is_exact_about_a_fixed_axis() -> None:
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(1e-3, 3e-3, 400))
    s = rng.normal(0.0, 3.0, t.size)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    table = OrientationTable.of(GyroTrace(t, s[:, None] * axis), t[0], t[-1])
    # inside the trace, at knots and between them, backwards too, and a little beyond its ends
    ta = np.concatenate([rng.uniform(t[5], t[-5], 60), t[[10, 20]], [t[0] - 0.01]])
    tb = np.concatenate([ta[:60] + rng.uniform(-0.05, 0.05, 60), t[[30, 15]], [t[-1] + 0.02]])
    got = np.stack(table.relative(ta, tb), axis=-1).reshape(-1, 3, 3)
    angle = _cumulative(t, s, tb) - _cumulative(t, s, ta)
    assert np.allclose(got, so3_exp(angle[:, None] * axis), atol=1e-12)
    # negative control: the same rates about another axis turn elsewhere
    other = OrientationTable.of(GyroTrace(t, s[:, None] * axis[[1, 2, 0]]), t[0], t[-1])
    moved = np.stack(other.relative(ta, tb), axis=-1).reshape(-1, 3, 3)
    assert np.max(np.abs(moved - got)) > 1e-2


def _angle(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return np.linalg.norm(so3_log(np.einsum("nji,njk->nik", A, B)), axis=1)


def test_orientation_table_is_closer_to_the_exact_rotation_than_1ms_substeps(problem) -> None:
    g = problem.gyro.upsampled(GYRO_UPSAMPLE)
    rng = np.random.default_rng(5)
    ta = rng.uniform(g.t_s[100], g.t_s[-100] - 0.04, 200)
    tb = ta + 1 / 30
    exact = np.stack(relative_rotation(ta, tb, g.omega_components, 4096), -1).reshape(-1, 3, 3)
    table = OrientationTable.of(g, float(ta.min()), float(tb.max()))
    got = np.stack(table.relative(ta, tb), axis=-1).reshape(-1, 3, 3)
    coarse = gyro_rotations(g, ta, tb, 0.0)
    assert np.median(_angle(exact, np.eye(3)[None].repeat(200, 0))) > 1e-3  # it does turn
    err_table, err_coarse = _angle(exact, got).max(), _angle(exact, coarse).max()
    assert err_table < 1e-6 and err_table < err_coarse


def test_covered_agrees_with_the_trace_interval_by_interval() -> None:
    t = np.delete(np.arange(0.0, 2.0, 0.005), np.r_[80:90, 250:252])  # two gaps
    gyro = GyroTrace(t, np.zeros((t.size, 3)))
    rng = np.random.default_rng(6)
    lo = rng.uniform(-0.1, 2.1, 500)
    hi = lo + rng.uniform(-0.3, 0.3, 500)  # reversed intervals too
    expected = np.array([gyro.covers(a, b) for a, b in zip(lo, hi, strict=True)])
    assert 50 < expected.sum() < 450
    assert np.array_equal(covered(gyro, lo, hi), expected)


def _brute(pts, pf, q, qf, cap):
    d = np.hypot(q[:, None, 0] - pts[None, :, 0], q[:, None, 1] - pts[None, :, 1])
    d[qf[:, None] != pf[None, :]] = np.inf
    return np.minimum(np.nan_to_num(d, nan=np.inf).min(axis=1), cap)


@pytest.mark.parametrize("max_cells", [CellIndex.MAX_CELLS, 40])
def test_cell_index_is_the_capped_nearest_distance_in_the_same_frame(monkeypatch, max_cells):
    monkeypatch.setattr(CellIndex, "MAX_CELLS", max_cells)
    rng = np.random.default_rng(7)
    pts = rng.uniform([0, 0], [640, 480], (600, 2))
    pts[:5] = pts[5] + rng.normal(0, 0.5, (5, 2))  # several points in one cell
    pf = rng.integers(2, 7, 600)
    q = np.concatenate(
        [
            pts + rng.normal(0, 8.0, pts.shape),
            rng.uniform([-100, -100], [740, 580], (400, 2)),  # outside the box too
            [[np.nan, 3.0], [np.inf, 5.0], [1e30, -1e30]],
        ]
    )
    qf = np.concatenate([pf, rng.integers(2, 7, 403)])
    cap = 12.0
    cells = CellIndex(pts, pf, cap)
    assert cells.depth > 1
    if max_cells == 40:
        assert cells.side > 2 * cap  # grown cells, same answers
    got = cells.capped_distance(q, qf)
    want = _brute(pts, pf, q, qf, cap)
    assert np.allclose(got, want, rtol=0, atol=1e-9)
    assert 0.2 < np.mean(want < cap) < 0.9
    # negative control: points of the other frames are not candidates
    assert not np.allclose(got[:600], _brute(pts, pf, q[:600], pf[rng.permutation(600)], cap))
    with pytest.raises(CalibError, match="frames"):
        cells.capped_distance(q[:3], np.array([2, 3, 9]))


def test_carried_points_are_the_candidates_rotation_of_the_bearings() -> None:
    rng = np.random.default_rng(8)
    cam = make_problem(seed=1, n_frames=3, dots_per_frame=5).initial.camera
    b = np.column_stack([rng.normal(0, 0.3, (50, 2)), np.ones(50)])
    Mt = so3_exp(rng.normal(0, 0.05, (50, 3)))
    P = proper_axis_permutations()[[0, 5, 17]]
    back = np.einsum("cji,nj->cin", P, b)
    got = carried_px(cast(Mat3, tuple(Mt.reshape(50, 9).T)), back, P, cam)
    for c in range(3):
        X = np.einsum("ij,njk,lk,nl->ni", P[c], Mt, P[c], b)
        assert np.allclose(got[c], cam.project(X), atol=1e-9)
    assert not np.allclose(got[0], got[1])
