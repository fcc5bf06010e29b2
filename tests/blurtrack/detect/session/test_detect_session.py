"""Session-level detection: start/end resolution, the table, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.detect import DetectParams
from blurtrack.detect.frame import FrameStreaks
from blurtrack.detect.session.orientation import (
    FrameTiming,
    combine,
    continuity_cues,
    continuity_llr,
)
from blurtrack.detect.session.pipeline import detect_session
from blurtrack.detect.session.table import EXTRA_COLUMNS, read_table, write_table
from blurtrack.errors import CoverageError, DetectionError
from blurtrack.io import streaks
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    folder = tmp_path_factory.mktemp("det") / "session"
    truth = write_synthetic_session(folder, n_frames=5, seed=3)
    return folder, truth


def _oriented_fraction(
    df: pd.DataFrame, truth: dict, min_len: float = 5.0
) -> tuple[int, int, list[float]]:
    tr = streaks.from_truth(truth)
    ok = n = 0
    errors: list[float] = []
    for _, r in tr.iterrows():
        d = df[df.frame == r.frame]
        mid = np.array([(r.start_x + r.end_x) / 2, (r.start_y + r.end_y) / 2])
        j = int(
            np.argmin(np.hypot(d.start_x + d.end_x - 2 * mid[0], d.start_y + d.end_y - 2 * mid[1]))
        )
        m = d.iloc[j]
        right = [
            np.hypot(m.start_x - r.start_x, m.start_y - r.start_y),
            np.hypot(m.end_x - r.end_x, m.end_y - r.end_y),
        ]
        wrong = [
            np.hypot(m.start_x - r.end_x, m.start_y - r.end_y),
            np.hypot(m.end_x - r.start_x, m.end_y - r.start_y),
        ]
        if r.length_px > min_len:
            n += 1
            ok += sum(right) < sum(wrong)
            errors += right
    return ok, n, errors


def test_gyro_resolves_start_and_end(synthetic: tuple[Path, dict]) -> None:
    folder, truth = synthetic
    res = detect_session(load_session(folder), gyro="on")
    ok, n, errors = _oriented_fraction(res.table, truth)
    assert n >= 30
    assert ok == n
    assert np.median(errors) < 0.3
    assert res.summary["orientation_sources"].get("gyro", 0) > 0.5 * len(res.table)
    assert res.summary["orientation_confidence_median"] > 0.99


def test_the_checks_residuals_and_model_errors_reach_the_table_and_summary(
    synthetic: tuple[Path, dict],
) -> None:
    """Derived truth: the synthetic rig's gyro and calibration are exact, so a streak's
    residual is how far its measured start-to-end vector lies from the true one, and the
    frames' model errors are near zero: no frame's tolerance lowered. Without a gyro the
    column is NaN and nothing is measured (the negative control)."""
    folder, truth = synthetic
    res = detect_session(load_session(folder), gyro="on")
    t, s = res.table, res.summary
    r = t.gyro_residual_px.to_numpy()
    assert np.isfinite(r).mean() > 0.8
    assert np.all(r[t.quality_ok.to_numpy() & np.isfinite(r)] <= 1.5)
    tr = streaks.from_truth(truth)
    err = []
    for row in t[np.isfinite(r)].itertuples():
        d = tr[tr.frame == row.frame]
        m = np.array([row.end_x - row.start_x, row.end_y - row.start_y])
        mid = np.array([row.start_x + row.end_x, row.start_y + row.end_y]) / 2
        j = int(
            np.argmin(
                np.hypot((d.start_x + d.end_x) / 2 - mid[0], (d.start_y + d.end_y) / 2 - mid[1])
            )
        )
        v = np.array([d.end_x.iloc[j] - d.start_x.iloc[j], d.end_y.iloc[j] - d.start_y.iloc[j]])
        err.append(min(np.hypot(*(m - v)), np.hypot(*(m + v))) - row.gyro_residual_px)
    assert abs(float(np.median(err))) < 0.2
    q = s["gyro_trust_model_error_px"]
    assert q is not None and q["median"] <= q["p90"] <= q["max"] < 0.5
    assert s["gyro_trust_lowered_frames"] == []
    off = detect_session(load_session(folder), gyro="off")
    assert off.table.gyro_residual_px.isna().all()
    assert off.summary["gyro_trust_model_error_px"] is None
    assert off.summary["gyro_trust_lowered_frames"] == []


def test_a_frame_whose_gyro_is_off_gets_lower_tolerances(tmp_path: Path) -> None:
    """Derived truth: 0.7 rad/s added to the gyro's x rate over frame 5's exposure (12 ms)
    moves that frame's predicted vectors by f * 0.7 * 0.012 = 2.42 px (f = 288 px) and no
    other frame's. The session's fit (eight frames, one off) stands; the check measures that
    frame's plain residuals at about 2.42 px, so its model error at about 2.42 px less the
    plain ends' share, and lowers that frame's tolerances only."""
    folder = tmp_path / "session"
    write_synthetic_session(folder, n_frames=8, seed=3, grid=(8, 6))
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    t0_s, exposure_s, bump = 6 / 30.0, 0.012, 0.7  # frame k starts at (k + 1) / fps
    rows = []
    for ln in lines[1:]:
        t_ns, wx, wy, wz = ln.split(",")
        if t0_s - 1e-3 < int(t_ns) * 1e-9 < t0_s + exposure_s + 1e-3:
            wx = repr(float(wx) + bump)
        rows.append(",".join([t_ns, wx, wy, wz]))
    csv.write_text("\n".join([lines[0], *rows]) + "\n")
    res = detect_session(load_session(folder), gyro="on")
    s = res.summary
    assert s["gyro_session_calibration"]["status"] == "fitted"
    assert s["gyro_trust_lowered_frames"] == [5]
    expected_px = 0.9 * 320 * bump * exposure_s
    plain_end_px = DetectParams().source.plain_end_px
    assert s["gyro_trust_model_error_px"]["max"] == pytest.approx(
        expected_px - plain_end_px, abs=0.3
    )
    r = res.table.groupby("frame")["gyro_residual_px"].median()
    assert r[5] == pytest.approx(expected_px, abs=0.3)
    assert r.drop(5).max() < 0.75
    # The negative control: the gyro as recorded lowers nothing.
    clean = tmp_path / "clean"
    write_synthetic_session(clean, n_frames=8, seed=3, grid=(8, 6))
    assert detect_session(load_session(clean), gyro="on").summary["gyro_trust_lowered_frames"] == []


def test_image_only_orientation_from_continuity(synthetic: tuple[Path, dict]) -> None:
    folder, truth = synthetic
    res = detect_session(load_session(folder), gyro="off")
    ok, n, _ = _oriented_fraction(res.table, truth)
    assert ok >= 0.8 * n
    assert set(res.table.orientation_source) <= {"continuity", "none"}
    assert (res.table.llr_gyro == 0).all()


def test_gyro_on_without_coverage_is_an_error(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_synthetic_session(folder, n_frames=2, seed=1, with_imu=False)
    session = load_session(folder)
    with pytest.raises(CoverageError):
        detect_session(session, gyro="on")
    res = detect_session(session, gyro="auto")  # image only, and said so
    assert res.summary["gyro"] == "off"


def test_table_schema_and_parquet_round_trip(synthetic: tuple[Path, dict], tmp_path: Path) -> None:
    folder, _ = synthetic
    res = detect_session(load_session(folder))
    path = tmp_path / "t.parquet"
    write_table(res.table, str(path))
    back = read_table(str(path))
    for col in list(streaks.COLUMNS) + list(EXTRA_COLUMNS):
        assert col in back.columns
    assert len(back) == len(res.table)
    row = back.iloc[0]
    cl = np.asarray(list(row["centerline"]), dtype=float).reshape(-1, 2)
    assert cl.shape[0] == len(row["profile"]) >= 2
    assert np.allclose(cl[0], [row.start_x, row.start_y], atol=1e-3)
    assert np.allclose(cl[-1], [row.end_x, row.end_y], atol=1e-3)
    assert row.length_px == pytest.approx(
        np.linalg.norm(np.diff(cl, axis=0), axis=1).sum(), abs=0.05
    )
    assert back["orientation_confidence"].between(0.5, 1.0).all()


def _streaks(ends_a: list, ends_b: list) -> FrameStreaks:
    a, b = np.array(ends_a, float), np.array(ends_b, float)
    pts = [np.linspace(p, q, int(np.linalg.norm(q - p)) + 1) for p, q in zip(a, b, strict=True)]
    n = len(a)
    return FrameStreaks(
        shape=(100, 100),
        end_a=a,
        end_b=b,
        time_mid=(a + b) / 2,
        plateau=np.ones((n, 2)),
        length_px=np.linalg.norm(b - a, axis=1),
        width_px=np.ones(n),
        snr=np.full(n, 50.0),
        points=pts,
        profile=[np.ones(len(p)) for p in pts],
        flags={},
        sigma_c_px=1.8,
        noise=0.01,
        hot_pixels=0,
        short=np.zeros(n, bool),
    )


def test_continuity_orients_a_chain_of_streaks() -> None:
    # A dot moving right at 1000 px/s; 10 ms exposures every 12 ms (2 px gaps). Frame 1's
    # streak is stored reversed (A at its right end): continuity must say "swap".
    timings = [FrameTiming(0.012 * k, 0.010) for k in range(3)]
    f0 = _streaks([[10, 50]], [[20, 50]])
    f1 = _streaks([[32, 50]], [[22, 50]])
    f2 = _streaks([[34, 50]], [[44, 50]])
    llr = continuity_cues([f0, f1, f2], timings)
    assert llr[0][0] > 2 and llr[2][0] > 2
    assert llr[1][0] < -2
    ori = combine(np.column_stack([np.zeros(1), np.zeros(1), llr[1]]))
    assert ori.swap[0] and ori.source == ["continuity"] and ori.confidence[0] > 0.9


def test_continuity_llr_is_bounded_by_the_density_of_other_ends() -> None:
    q, u, lam = 0.75, np.array([2.0]), np.array([1e-3])
    at_zero = continuity_llr(np.array([0.0]), u, lam, q)[0]
    assert at_zero == pytest.approx(np.log(1 + q / (2 * np.pi * 1e-3 * 4.0)))
    assert continuity_llr(np.array([1e3]), u, lam, q)[0] == pytest.approx(np.log(1 - q))
    # Falls with the distance, to the floor of a missing end.
    d = np.linspace(0.0, 8.0, 50)
    assert np.all(np.diff(continuity_llr(d, np.full(50, 2.0), np.full(50, 1e-3), q)) < 0)
    # Ten times the clutter: an end right there says less, but still for.
    crowded = continuity_llr(np.array([0.0]), u, 10 * lam, q)[0]
    assert 0 < crowded < at_zero - 1.0


def test_continuity_weighs_a_near_end_less_among_other_ends() -> None:
    # The chain of test_continuity_orients_a_chain_of_streaks, frame 1 stored the right way.
    timings = [FrameTiming(0.012 * k, 0.010) for k in range(3)]
    chain = [([10, 50], [20, 50]), ([22, 50], [32, 50]), ([34, 50], [44, 50])]

    def frame1_llr(strangers: list) -> float:
        a0 = [chain[0][0]] + [[x, y] for x, y in strangers]
        b0 = [chain[0][1]] + [[x + 1, y] for x, y in strangers]
        frames = [_streaks(a0, b0), _streaks([chain[1][0]], [chain[1][1]])]
        frames.append(_streaks([chain[2][0]], [chain[2][1]]))
        return float(continuity_cues(frames, timings)[1][0])

    lone = frame1_llr([])
    # Other dots' tiny streaks 5-8 px about the extrapolated start (20, 50): its own end is
    # still the nearest, and the orientation still right, but less sure.
    ring = [[20 + 6 * np.cos(t), 50 + 6 * np.sin(t)] for t in np.linspace(0, 6, 8)]
    crowded = frame1_llr(ring)
    assert lone > 4.0
    assert 0.5 < crowded < lone - 1.0
    # Negative control: the same strangers beyond the counting radius change nothing.
    far = [[x + 60, y + 40] for x, y in ring]
    assert frame1_llr(far) == pytest.approx(lone, abs=1e-12)


def test_continuity_cache_gives_the_same_cues() -> None:
    timings = [FrameTiming(0.012 * k, 0.010) for k in range(3)]
    frames = [
        _streaks([[10, 50], [60, 20]], [[20, 50], [70, 24]]),
        _streaks([[32, 50], [72, 25]], [[22, 50], [82, 29]]),
        _streaks([[34, 50], [84, 30]], [[44, 50], [94, 34]]),
    ]
    plain = continuity_cues(frames, timings)
    cache: dict = {}
    first = continuity_cues(frames, timings, cache=cache)
    assert sorted(cache) == [0, 1, 2]
    swaps = [np.array([False, False]), np.array([True, False]), np.array([False, False])]
    again = continuity_cues(frames, timings, swaps, cache=cache)
    for a, b, c, d in zip(
        plain, first, again, continuity_cues(frames, timings, swaps), strict=True
    ):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(c, d)
    # Negative control: the cache is what is used (a stale one changes the cues).
    stale = {k: (-oa, -ob, sp) for k, (oa, ob, sp) in cache.items()}
    moved = continuity_cues(frames, timings, cache=stale)
    assert not all(np.array_equal(a, b) for a, b in zip(plain, moved, strict=True))


def test_combine_without_evidence_is_undecided() -> None:
    ori = combine(np.zeros((2, 3)))
    assert not ori.swap.any()
    assert ori.source == ["none", "none"]
    assert np.allclose(ori.confidence, 0.5)


def test_cli_detect_writes_table_summary_and_overlay(
    synthetic: tuple[Path, dict], tmp_path: Path
) -> None:
    folder, _ = synthetic
    out = tmp_path / "out" / "streaks.parquet"
    png = tmp_path / "out" / "overlay.png"
    assert main(["detect", str(folder), "--out", str(out), "--overlay", str(png)]) == 0
    df = pd.read_parquet(out)
    assert len(df) > 0 and {"start_x", "centerline", "orientation_source"} <= set(df.columns)
    summary = json.loads((tmp_path / "out" / "streaks.summary.json").read_text())
    assert summary["streaks"] == len(df)
    assert png.stat().st_size > 1000


def test_cli_detect_bad_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["detect", str(tmp_path / "missing"), "--out", str(tmp_path / "x.parquet")]) == 2
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "x.parquet").exists()


def test_session_without_any_dots_is_reported(tmp_path: Path) -> None:
    folder = tmp_path / "dark"
    write_synthetic_session(folder, n_frames=2, seed=0, grid=(0, 0))
    with pytest.raises(DetectionError, match="no laser-dot streaks"):
        detect_session(load_session(folder))


def test_timeshift_scan_recovers_a_wrong_initial_offset(tmp_path: Path) -> None:
    from blurtrack.detect.gyro.timeshift import estimate_timeshift
    from blurtrack.detect.session.orientation import FrameTiming

    folder = tmp_path / "shifted"
    write_synthetic_session(folder, n_frames=5, seed=7, timeshift_s=0.018)
    session = load_session(folder)
    frames = detect_session(session, gyro="off").frames
    timings = [
        FrameTiming(float(t), float(e))
        for t, e in zip(session.frame_times_s, session.exposures_s, strict=True)
    ]
    est = estimate_timeshift(
        frames, timings, session.initial_calibration(), session.gyro(), search_s=0.03
    )
    assert est is not None and est.initial_s == 0.0
    assert est.timeshift_s == pytest.approx(0.018, abs=0.0015)
    res = detect_session(session, gyro="auto")
    assert res.summary["gyro_timeshift_s"] == pytest.approx(0.018, abs=0.0015)
    # Straight streaks that match their predictions: the template pass's gate lets no frame
    # through, so the templates do not refine the scan's shift or the session's readout.
    assert res.summary["gyro_timeshift_refinement"] == "not needed"
    assert res.summary["gyro_timeshift_s"] == res.summary["gyro_timeshift_scan_s"]
    assert res.summary["gyro_readout_s"] == session.initial_calibration().camera.readout_s


def test_continuity_in_parts_is_the_same_as_all_at_once() -> None:
    from blurtrack.detect.session.cues import continuity_columns, continuity_parts
    from blurtrack.detect.session.orientation import CueErrors

    # Two dots moving right at 1000 px/s, 10 ms exposures every 12 ms, over 7 frames; some
    # streaks stored reversed, and gyro LLRs that disagree with some, so that the second
    # (tentative-orientation) pass reads the neighbouring frames' first-pass columns.
    timings = [FrameTiming(0.012 * k, 0.010) for k in range(7)]
    frames, llrs = [], []
    for k in range(7):
        a = [[10 + 12 * k, 50], [300 + 12 * k, 80 + k]]
        b = [[20 + 12 * k, 50], [310 + 12 * k, 81 + k]]
        rev = [k % 3 == 1, k % 2 == 0]
        a2 = [bb if r else aa for aa, bb, r in zip(a, b, rev, strict=True)]
        b2 = [aa if r else bb for aa, bb, r in zip(a, b, rev, strict=True)]
        frames.append(_streaks(a2, b2))
        llr = np.zeros((2, 3))
        llr[:, 0] = [0.5 if k % 2 else -0.5, -1.0 if k == 3 else 0.2]
        llrs.append(llr)
    errors = CueErrors()
    whole = continuity_columns(frames, timings, llrs, errors)
    assert any(abs(c).max() > 1 for c in whole)
    for parts in (1, 2, 3, 7, 9):
        ranges = continuity_parts(len(frames), parts)
        assert [k for r in ranges for k in r] == list(range(7))
        got = [c for r in ranges for c in continuity_columns(frames, timings, llrs, errors, r)]
        for a, b in zip(whole, got, strict=True):
            np.testing.assert_array_equal(a, b)
    assert all(llr[:, 2].tolist() == [0.0, 0.0] for llr in llrs)  # the input stays as it was
    # Negative control: a part computed on its own frames alone (no neighbours beyond it)
    # is not the same at its edges.
    alone = continuity_columns(frames[:3], timings[:3], llrs[:3], errors)
    assert not np.array_equal(alone[2], whole[2])
