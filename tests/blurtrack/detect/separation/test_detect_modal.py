"""Whole-component references of template separation (blurtrack.detect.separation.modal), on exactly
rendered frames of "2"-shaped streaks (the trails of real point lights under hand shake)."""

from __future__ import annotations

import numpy as np

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.context import FrameContext
from blurtrack.detect.image import prepare_frame
from blurtrack.detect.lines.segment import Components, find_components
from blurtrack.detect.params import SeparationParams
from blurtrack.detect.separation.modal import component_references, modal_components, skeleton_path
from blurtrack.testing.streak_frames import quantise, render_streaks

SHAPE = (300, 420)
SIGMA = 1.3


def _two(origin: np.ndarray, n: int = 900) -> np.ndarray:
    """A "2": a hook (slow: bright), a diagonal down to the left and a foot to the right,
    sampled uniformly in time."""
    th = np.linspace(np.pi, 2 * np.pi + 0.6, 60)
    hook = np.stack([6 + 6 * np.cos(th), 6 + 6 * np.sin(th)], axis=1)
    diag = np.linspace(hook[-1], [0.0, 24.0], 40)[1:]
    foot = np.linspace([0.0, 24.0], [12.0, 24.0], 20)[1:]
    p = np.vstack([hook, diag, foot])
    speed = np.where(np.arange(len(p)) < 60, 0.35, 1.0)[:-1]
    t = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T) / speed)])
    u = np.linspace(0.0, t[-1], n)
    return origin + np.stack([np.interp(u, t, p[:, 0]), np.interp(u, t, p[:, 1])], axis=1)


def _frame(extra: list[np.ndarray] | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    curves = [_two(np.array([20.0 + 45 * i, 20.0 + 60 * j])) for i in range(8) for j in range(2)]
    image = render_streaks(SHAPE, curves + (extra or []), 1.0, SIGMA, noise=0.004, seed=2)
    return quantise(image), curves


def _components(image: np.ndarray) -> tuple[Components, FrameContext]:
    """The frame's components (artefacts kept) and its context (saturation ignored)."""
    p = DetectParams()
    prep = prepare_frame(image, p.smooth_sigma_px, p.hot_pixel_ratio, p.saturation_level)
    thr = max(p.threshold_snr * prep.noise_smooth, p.min_threshold)
    comps = find_components(prep.smooth, thr, p.min_area_px, p.max_streaks)
    ctx = FrameContext(
        prep.smooth, prep.signal, prep.saturation, None, comps, thr, prep.noise_smooth, p
    )
    return comps, ctx


def _whole(end_a: np.ndarray, end_b: np.ndarray, curves: list[np.ndarray], tol: float) -> int:
    """How many true streaks have a detection with both ends (either order) within ``tol``."""
    det = np.stack([end_a, end_b], axis=1)
    found = 0
    for c in curves:
        e = np.stack([c[0], c[-1]])
        d = np.minimum(
            np.linalg.norm(det - e[None], axis=2).max(axis=1),
            np.linalg.norm(det - e[None, ::-1], axis=2).max(axis=1),
        )
        found += int(np.any(d < tol))
    return found


def test_modal_cluster_is_the_isolated_streaks() -> None:
    # Two chains of two touching "2"s (twice the area) and three short fragments besides
    # the sixteen isolated ones.
    chain = [_two(np.array([40.0 + 150 * k, 150.0])) for k in range(2)]
    chain += [c + np.array([1.0, 26.0]) for c in chain]
    frags = [np.linspace([60.0 + 120 * k, 250.0], [66.0 + 120 * k, 252.0], 100) for k in range(3)]
    image, curves = _frame(chain + frags)
    comps, _ = _components(image)
    H, W = SHAPE
    x, y, w, h = comps.boxes.T
    modal = modal_components(
        comps, (x > 0) & (y > 0) & (x + w < W) & (y + h < H), SeparationParams()
    )
    centre = np.stack([x + w / 2, y + h / 2], axis=1)[modal]
    truth = np.array([c.mean(axis=0) for c in curves])
    # Exactly the isolated ones: each member lies on one of them, each of them is a member.
    d = np.linalg.norm(centre[:, None] - truth[None], axis=2)
    assert modal.sum() == len(curves)
    assert np.all(d.min(axis=1) < 6.0) and np.all(d.min(axis=0) < 6.0)
    # Negative control: with the isolated ones far from the border excluded, the modal
    # cluster is not made of them.
    away = np.ones(comps.ids.size, bool)
    away[np.flatnonzero(modal)] = False
    rest = modal_components(comps, away, SeparationParams())
    assert not np.any(rest & modal)


def test_skeleton_path_runs_from_end_to_end_in_order() -> None:
    image, curves = _frame()
    comps, _ = _components(image)
    c = curves[0]
    i = int(
        np.argmin(np.linalg.norm(comps.boxes[:, :2] + comps.boxes[:, 2:] / 2 - c.mean(0), axis=1))
    )
    bx, by, bw, bh = comps.boxes[i]
    path = skeleton_path(comps.labels[by : by + bh, bx : bx + bw] == comps.ids[i]) + np.array(
        [bx, by]
    )
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.all(steps <= np.sqrt(2) + 1e-9)  # 8-connected, in order
    ends = path[[0, -1]]
    e = np.stack([c[0], c[-1]])
    d = min(np.linalg.norm(ends - e, axis=1).max(), np.linalg.norm(ends - e[::-1], axis=1).max())
    assert d < 4.0  # the skeleton stops within about the streak's half-width of its ends
    # It follows the curve: every true point away from the ends is near the path (the
    # skeleton cuts the sharp corner above the foot by up to a few px; the measurement
    # moves the line onto the light's centroid).
    gap = np.linalg.norm(c[45:-45:10, None] - path[None], axis=2).min(axis=1)
    assert gap.max() < 6.0 and np.median(gap) < 1.0


def test_component_references_are_whole_where_the_first_pass_cuts_the_foot() -> None:
    image, curves = _frame()
    _, ctx = _components(image)
    sc = float(np.sqrt(SIGMA**2 + DetectParams().smooth_sigma_px ** 2 + 1.0 / 12.0))
    out = component_references(ctx, sc, sc)
    assert out is not None
    m, field = out
    assert _whole(m.end_a, m.end_b, curves, 1.5) >= 14
    # The consensus is the true start-to-end vector (12, 18) up to its sign.
    c = field.at(np.array([[200.0, 100.0]]))[0]
    truth = np.array([12.0, 18.0])
    assert min(np.linalg.norm(c - truth), np.linalg.norm(c + truth)) < 1.5
    # Negative control: the first pass loses the foot of these streaks at its corner.
    plain = detect_frame(image, DetectParams(separate=False))
    assert _whole(plain.end_a, plain.end_b, curves, 1.5) <= 4


def test_real_string_lights_come_out_whole(shared_data) -> None:
    """night2.jpg (rows of small lights, every one the same "2", touching in columns): the
    first pass finds too few line references, so separation takes whole components."""
    import cv2

    image = cv2.imread(str(shared_data / "real" / "light-streaks" / "night2.jpg"))
    _, ctx = _components(image)
    out = component_references(ctx, 2.0, 2.0)
    assert out is not None
    m, field = out
    v = (m.end_b - m.end_a)[field.use]
    v = v * np.where(v[:, 1] < 0, -1.0, 1.0)[:, None]
    ref = np.median(v, axis=0)
    assert 25.0 < np.hypot(*ref) < 45.0  # the README: every light drew a ~25 px tall curve

    def whole(fs) -> int:
        d = fs.end_b - fs.end_a
        dev = np.minimum(np.hypot(*(d - ref).T), np.hypot(*(d + ref).T))
        return int(np.sum(~fs.flags["clipped"] & (dev <= 0.25 * np.hypot(*ref))))

    sep = whole(detect_frame(image))
    plain = whole(detect_frame(image, DetectParams(separate=False)))
    # Negative control: without separation the lights split at their hooks and chain.
    assert sep >= 40 and sep >= 3 * plain
