"""Building blocks of detection: ragged polylines, edge fits, saturation, parameters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

from blurtrack.detect.lines import ragged
from blurtrack.detect.lines.endpoints import clipped_integral, fit_edges, unclip_profiles
from blurtrack.detect.lines.skeleton import trace_paths
from blurtrack.detect.params import DetectParams
from blurtrack.errors import ConfigError


def test_resample_keeps_ends_and_spacing() -> None:
    lines = [np.array([[0.0, 0.0], [3.5, 0.0], [3.5, 2.0]]), np.array([[5.0, 5.0], [5.0, 9.3]])]
    out = ragged.resample(ragged.Ragged.from_list(lines)).split()
    for r, src in zip(out, lines, strict=True):
        assert np.allclose(r[0], src[0]) and np.allclose(r[-1], src[-1])
        steps = np.linalg.norm(np.diff(r, axis=0), axis=1)
        assert np.allclose(steps, steps[0], atol=0.3) and abs(steps[0] - 1.0) < 0.2
    assert np.allclose(out[1][:, 0], 5.0)


def test_extend_and_cut_are_inverse_on_straight_lines() -> None:
    r = ragged.resample(
        ragged.Ragged.from_list(
            [np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[0.0, 5.0], [0.0, 12.0]])]
        )
    )
    e = ragged.extend(r, 3)
    assert list(e.sizes) == [r.sizes[0] + 6, r.sizes[1] + 6]
    first = e.split()[0]
    assert np.allclose(first[0], [-3.0, 0.0]) and np.allclose(first[-1], [13.0, 0.0])
    keep = np.zeros(e.points.shape[0], bool)
    for start, size in zip(e.starts, e.sizes, strict=True):
        keep[start + 3 : start + size - 3] = True
    back = ragged.cut(e, keep)
    assert np.allclose(back.points, r.points)


def test_smooth_preserves_straight_lines_and_ends() -> None:
    p = np.stack([np.arange(10.0), 2 * np.arange(10.0) + 1], axis=1)
    s = ragged.smooth(ragged.Ragged.from_list([p])).points
    assert np.allclose(s, p)


def _erf_profile(length: float, s0: float, sigma: float, plateau: float, n: int) -> np.ndarray:
    s = np.arange(n, dtype=float)
    return plateau * (ndtr((s - s0) / sigma) - ndtr((s - s0 - length) / sigma))


@settings(max_examples=40, deadline=None)
@given(
    length=st.floats(14.0, 60.0),
    s0=st.floats(8.0, 12.0),
    sigma=st.floats(1.2, 2.5),
    plateau=st.floats(0.3, 5.0),
)
def test_edge_fit_recovers_erf_endpoints(
    length: float, s0: float, sigma: float, plateau: float
) -> None:
    n = int(s0 + length + 12)
    A = _erf_profile(length, s0, sigma, plateau, n)[None, :]
    fit = fit_edges(A, np.array([n]), np.array([sigma]))
    assert fit.valid[0]
    assert fit.pos_a[0] == pytest.approx(s0, abs=0.03)
    assert fit.pos_b[0] == pytest.approx(s0 + length, abs=0.03)
    if not fit.short[0]:
        assert fit.plateau_a[0] == pytest.approx(plateau, rel=0.01)


def _time_law_profile(length: float, s0: float, sigma: float, gamma: float, n: int) -> np.ndarray:
    """Blurred profile of a dot under constant acceleration (position fraction
    ``t + gamma t (1 - t)``, speed falling from ``1 + gamma`` to ``1 - gamma``): light per
    sample is time per sample, by dense sampling in time."""
    t = np.linspace(0.0, 1.0, 40001)
    x = s0 + length * (t + gamma * t * (1.0 - t))
    s = np.arange(n, dtype=float)
    prof = np.zeros(n)
    for chunk in np.array_split(x, 20):
        prof += ndtr((s[:, None] + 0.5 - chunk[None, :]) / sigma).sum(axis=1)
        prof -= ndtr((s[:, None] - 0.5 - chunk[None, :]) / sigma).sum(axis=1)
    return prof * (length / x.size)


@settings(max_examples=25, deadline=None)
@given(length=st.floats(16.0, 50.0), sigma=st.floats(1.3, 2.2), gamma=st.floats(-0.45, 0.45))
def test_edge_fit_follows_an_accelerating_dot(length: float, sigma: float, gamma: float) -> None:
    # Brightness 1 / speed is convex along the streak; both ends within 0.06 px (a linear
    # density extrapolated to the ends put them up to 0.2 px outside at |gamma| = 0.4).
    n = int(10 + length + 12)
    A = _time_law_profile(length, 10.0, sigma, gamma, n)[None, :]
    fit = fit_edges(A, np.array([n]), np.array([np.sqrt(sigma**2 + 1 / 12)]))
    assert fit.valid[0] and not fit.short[0]
    assert fit.pos_a[0] == pytest.approx(10.0, abs=0.06)
    assert fit.pos_b[0] == pytest.approx(10.0 + length, abs=0.06)


def _lit_end_profile(kind: str, gap_sigmas: float, sigma: float) -> tuple[np.ndarray, float]:
    """A 30-sample erf streak with a faint neighbour (0.3 of its plateau) ``gap_sigmas``
    beyond its first end: a still light (a Gaussian of the edge's sigma) or a collinear
    streak ending there; a long tail beyond (baseline samples). The profile and ``s0``."""
    s0 = 12.0 + gap_sigmas * sigma + 6.0
    n = int(s0 + 30.0 + 12.0)
    A = _erf_profile(30.0, s0, sigma, 1.0, n)
    s = np.arange(n, dtype=float)
    at = s0 - gap_sigmas * sigma
    if kind == "spot":
        A = A + 0.3 * np.exp(-0.5 * ((s - at) / sigma) ** 2)
    else:
        A = A + 0.3 * ndtr((at - s) / sigma)
    return A, s0


@pytest.mark.parametrize(
    ("kind", "gap_sigmas"),
    [("spot", 4.0), ("spot", 5.0), ("spot", 6.0), ("line", 3.0), ("line", 4.0), ("line", 6.0)],
)
def test_edge_fit_ignores_light_past_a_dip(kind: str, gap_sigmas: float) -> None:
    # The neighbour's light past the profile's dip is not read: the end within 0.08 px (what
    # remains is the neighbour's own tail inside the dip, 0.3 sigma G(-1.5) = 0.015 px at 3
    # sigmas, and the dip's position on whole samples); the area from 3 sigma + 1 out with a
    # baseline from the tail put it 0.2 to 2.7 px off.
    A, s0 = _lit_end_profile(kind, gap_sigmas, 1.7)
    n = A.size
    fit = fit_edges(A[None, :], np.array([n]), np.array([1.7]))
    assert fit.valid[0] and not fit.short[0]
    assert fit.pos_a[0] == pytest.approx(s0, abs=0.08)
    assert fit.pos_b[0] == pytest.approx(s0 + 30.0, abs=0.03)


def test_edge_fit_is_still_moved_by_light_without_a_dip() -> None:
    # Negative control: a faint still light 2 sigmas beyond the end leaves no dip: the end
    # moves outwards by over 1 px, which is why trust.END_GAP_SIGMAS..+END_REACH_SIGMAS
    # (3 to 4 sigmas beyond the end) stays an ``end_light`` doubt.
    A, s0 = _lit_end_profile("spot", 2.0, 1.7)
    fit = fit_edges(A[None, :], np.array([A.size]), np.array([1.7]))
    assert s0 - fit.pos_a[0] > 1.0


@pytest.mark.parametrize("length", [0.5, 2.0, 5.0, 9.0])
def test_short_profiles_use_moments(length: float) -> None:
    A = _erf_profile(length, 10.0, 1.8, 1.0, 32)[None, :]
    fit = fit_edges(A, np.array([32]), np.array([1.8]))
    assert fit.short[0] and fit.valid[0]
    assert fit.pos_b[0] - fit.pos_a[0] == pytest.approx(length, abs=0.05)
    assert 0.5 * (fit.pos_a[0] + fit.pos_b[0]) == pytest.approx(10.0 + length / 2, abs=0.01)


def test_empty_profile_is_invalid() -> None:
    fit = fit_edges(np.zeros((1, 20)), np.array([20]), np.array([1.8]))
    assert not fit.valid[0]


def test_unclip_inverts_clipped_integral() -> None:
    a = np.linspace(0.1, 20.0, 50)
    J = clipped_integral(a, 1.0, 1.5)
    assert np.all(np.diff(J) > 0)
    assert np.allclose(J[a * 0.266 < 1.0], a[a * 0.266 < 1.0])  # below the knee: identity
    assert np.allclose(unclip_profiles(J[None, :], 1.0, 1.5)[0], a, rtol=1e-3)


def test_skeleton_splits_an_x_into_two_paths() -> None:
    mask = np.zeros((41, 41), bool)
    for k in range(41):
        mask[k, max(k - 1, 0) : k + 2] = True
        mask[k, max(39 - k, 0) : 42 - k] = True
    paths = trace_paths(mask, 5.0, 5.0)
    assert len(paths) == 2  # (the frame level flags a component with 2 paths as crossing)
    for p in paths:
        d = p.points[-1] - p.points[0]
        assert abs(abs(d[0]) - abs(d[1])) < 4 and np.linalg.norm(d) > 45


def test_params_yaml_round_trip_and_validation(tmp_path: Path) -> None:
    p = DetectParams(threshold_snr=5.0, psf_sigma_px=1.2)
    p.to_yaml(tmp_path / "p.yaml")
    assert DetectParams.from_yaml(tmp_path / "p.yaml") == p
    with pytest.raises(ConfigError):
        DetectParams(threshold_snr=-1.0)
    with pytest.raises(ConfigError):
        DetectParams(smooth_sigma_px=float("nan"))
    with pytest.raises(ConfigError, match="unknown"):
        DetectParams.from_dict({"bogus": 1})
    with pytest.raises(ConfigError, match="artefact_ratio"):
        DetectParams(artefact_ratio=1.5)
    with pytest.raises(ConfigError, match="artefact_gap_px"):
        DetectParams(artefact_gap_px=-1)
    with pytest.raises(ConfigError, match="separate"):
        DetectParams.from_dict({"separate": "yes"})
    assert DetectParams.from_dict({"separate": False, "artefact_ratio": 0.0}).separate is False
    (tmp_path / "bad.yaml").write_text("threshold_snr: [1, 2\n")
    with pytest.raises(ConfigError):
        DetectParams.from_yaml(tmp_path / "bad.yaml")
