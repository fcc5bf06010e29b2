"""Frame-parallel detection and the time-shift scan's bad inputs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from blurtrack.cli import main
from blurtrack.detect.session.pipeline import detect_session
from blurtrack.errors import CoverageError, DetectionError
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session


@pytest.fixture(scope="module")
def session_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("workers") / "s"
    write_synthetic_session(folder, n_frames=5, seed=4, timeshift_s=0.01)
    return folder


def test_workers_give_the_same_table_as_one_process(session_folder: Path) -> None:
    session = load_session(session_folder)
    one = detect_session(session, workers=1)
    seen: list[int] = []
    two = detect_session(session, workers=2, on_frame=lambda i, fs: seen.append(i))
    assert seen == list(range(5))  # progress in frame order
    pd.testing.assert_frame_equal(one.table, two.table, check_exact=True)
    assert one.summary == two.summary
    three = detect_session(session, workers=3, frames=range(1, 4))
    pd.testing.assert_frame_equal(
        three.table,
        detect_session(session, workers=1, frames=range(1, 4)).table,
        check_exact=True,
    )


def test_bad_worker_count_is_an_error(session_folder: Path) -> None:
    with pytest.raises(DetectionError, match="workers"):
        detect_session(load_session(session_folder), workers=0)


def test_timeshift_found_and_printed(session_folder: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "t.parquet"
    assert main(["detect", str(session_folder), "--out", str(out), "--workers", "2"]) == 0
    text = capsys.readouterr().out
    assert "camera-IMU time shift: +10." in text or "camera-IMU time shift: +9." in text


def _scaled_gyro(session_folder: Path, folder: Path, scale: float) -> Path:
    """A copy of the session whose gyro rates are ``scale`` times the recorded ones."""
    import shutil

    shutil.copytree(session_folder, folder)
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    rows = []
    for ln in lines[1:]:
        t, *w = ln.split(",")
        rows.append(",".join([t, *(repr(scale * float(v)) for v in w[:3]), *w[3:]]))
    csv.write_text("\n".join([lines[0], *rows]) + "\n")
    return folder


@pytest.mark.parametrize(("scale", "words"), [(0.0, "dead"), (12.0, "degrees/s")])
def test_a_gyro_that_does_not_move_the_dots_is_not_used_and_nothing_is_ok(
    session_folder: Path, tmp_path: Path, capsys, scale: float, words: str
) -> None:
    # All zeros, or rates far too large: in degrees/s where radians/s are due (57x; on a
    # `dense` session, whose rates stay under the load's 100 rad/s bound, the blur model's
    # integration of the rotation ran out of memory before), 12x here: the gyro's motion
    # contradicts the images'.
    folder = _scaled_gyro(session_folder, tmp_path / "g", scale)
    res = detect_session(load_session(folder))
    m = res.summary["gyro_motion"]
    assert m["status"] == "contradicted" and words in m["message"]
    assert m["image_px"] > 5.0 and (m["gyro_px"] < 0.01 or m["gyro_px"] > 10.0 * m["image_px"])
    assert res.summary["gyro_timeshift_status"] == "gyro not used"
    assert res.summary["gyro_timeshift_s"] is None
    assert len(res.table) > 0 and np.all(res.table.llr_gyro == 0)
    assert not np.any(res.table.orientation_source == "gyro")
    # No streak is quality_ok; those the images alone pass are the gyro's mismatch.
    assert res.summary["quality_ok"] == 0 and not res.table.quality_ok.any()
    off = detect_session(load_session(folder), gyro="off").table
    assert off.quality_ok.sum() > 0 and m["refused"] == int(off.quality_ok.sum())
    assert set(res.table.reason[off.quality_ok.to_numpy()]) == {"gyro_mismatch"}
    np.testing.assert_array_equal(
        res.table.reason[~off.quality_ok.to_numpy()].to_numpy(),
        off.reason[~off.quality_ok.to_numpy()].to_numpy(),
    )
    # The command says why, and keeps its exit 0; with --gyro on it stops with that line.
    assert main(["detect", str(folder), "--out", str(tmp_path / "z.parquet")]) == 0
    err = capsys.readouterr().err
    assert "warning: the gyro and the frames disagree on the motion" in err
    assert "no streak is quality_ok" in err
    with pytest.raises(DetectionError, match=words):
        detect_session(load_session(folder), gyro="on")


def test_a_right_gyro_agrees_with_the_images(session_folder: Path) -> None:
    m = detect_session(load_session(session_folder)).summary["gyro_motion"]
    assert m["status"] == "agrees" and "message" not in m and m["refused"] == 0
    assert 0.5 < m["gyro_px"] / m["image_px"] < 2.0


def _rewrite_frames(folder: Path, edit) -> None:
    import cv2

    for k, png in enumerate(sorted((folder / "cam0" / "data").glob("*.png"))):
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), edit(k, img))


def test_dark_and_saturated_frames_are_reported(session_folder: Path, tmp_path: Path, capsys):
    import shutil

    folder = tmp_path / "bad"
    shutil.copytree(session_folder, folder)
    names = sorted(p.name for p in (folder / "cam0" / "data").glob("*.png"))
    order = load_session(folder).frames
    dark = names.index(str(order["filename"].iloc[1]))
    sat = names.index(str(order["filename"].iloc[3]))

    def edit(k: int, img: np.ndarray) -> np.ndarray:
        if k == dark:
            return np.zeros_like(img)
        if k == sat:
            return np.full_like(img, 255)
        return img

    _rewrite_frames(folder, edit)
    res = detect_session(load_session(folder), workers=2)
    assert res.summary["frames_without_streaks"] == [1, 3]
    assert res.summary["frames_overexposed"] == [3]
    assert set(res.table.frame) == {0, 2, 4}
    assert main(["detect", str(folder), "--out", str(tmp_path / "b.parquet")]) == 0
    err = capsys.readouterr().err
    assert "2 frame(s) without streaks" in err and "1 over-exposed frame(s)" in err


@pytest.mark.parametrize("kind", ["uint16", "colour"])
def test_16_bit_and_colour_sessions_match_gray(session_folder: Path, tmp_path: Path, kind: str):
    import shutil

    folder = tmp_path / kind
    shutil.copytree(session_folder, folder)
    if kind == "uint16":
        _rewrite_frames(folder, lambda k, img: img.astype(np.uint16) * 257)
    else:
        _rewrite_frames(folder, lambda k, img: np.dstack([img // 3, img, img // 2]))
    a = detect_session(load_session(session_folder), gyro="off", refine_timeshift=False).table
    b = detect_session(load_session(folder), gyro="off", refine_timeshift=False).table
    assert len(a) == len(b)
    d = np.hypot(a.start_x - b.start_x, a.start_y - b.start_y)
    assert float(np.median(d)) < 0.05


def test_meanwhile_runs_once_and_changes_nothing(session_folder: Path) -> None:
    session = load_session(session_folder)
    calls: list[int] = []
    for workers in (1, 2):
        res = detect_session(session, workers=workers, meanwhile=lambda: calls.append(1))
        assert len(calls) == workers  # once per run, with or without worker processes
        assert res.summary["gyro_timeshift_status"] == "found"
    pd.testing.assert_frame_equal(res.table, detect_session(session).table, check_exact=True)


def test_timeshift_scan_with_the_resampled_trace_given_is_the_same(session_folder: Path) -> None:
    from blurtrack.detect.gyro.timeshift import estimate_timeshift
    from blurtrack.detect.session.orientation import FrameTiming
    from blurtrack.geometry.gyro import GYRO_UPSAMPLE

    session = load_session(session_folder)
    res = detect_session(session, gyro="off")
    timings = [
        FrameTiming(float(t), float(e))
        for t, e in zip(session.frame_times_s, session.exposures_s, strict=True)
    ]
    calib, trace = session.initial_calibration(), session.gyro()
    plain = estimate_timeshift(res.frames, timings, calib, trace)
    given = estimate_timeshift(
        res.frames, timings, calib, trace, model_gyro=trace.upsampled(GYRO_UPSAMPLE)
    )
    assert plain is not None and given is not None and plain.status == "found"
    np.testing.assert_array_equal(plain.cost, given.cost)
    assert plain.timeshift_s == given.timeshift_s
    # Negative control: a trace resampled otherwise gives other costs.
    other = estimate_timeshift(res.frames, timings, calib, trace, model_gyro=trace.upsampled(2))
    assert other is not None and not np.array_equal(other.cost, plain.cost)


def test_frames_pickle_back_unchanged(session_folder: Path) -> None:
    import pickle

    from blurtrack.detect.frame import _pack, _unpack

    fs = detect_session(load_session(session_folder), gyro="off").frames[0]
    back = pickle.loads(pickle.dumps(fs, protocol=pickle.HIGHEST_PROTOCOL))
    assert len(back) == len(fs) > 5
    for name in ("points", "profile"):
        a, b = getattr(fs, name), getattr(back, name)
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y)
    for name in ("end_a", "end_b", "time_mid", "plateau", "length_px", "width_px", "snr"):
        np.testing.assert_array_equal(getattr(fs, name), getattr(back, name))
    # Arrays that do not share a dtype stay a list (and come back as they were).
    mixed = [np.zeros((3, 2)), np.zeros((2, 2), np.float32)]
    assert isinstance(_pack(mixed), list)
    assert [x.dtype for x in _unpack(_pack(mixed))] == [np.float64, np.float32]
    assert isinstance(_pack([np.zeros(3), np.ones(4)]), tuple)


def _hairpin_shake(fps: float, reach_px: float, drift_px: float, f_px: float):
    """A ``shake`` stand-in that draws hairpins (as in test_detect_gyropass): about y, one
    period per frame, out and back within an exposure of half a period; about x, a drift."""
    period = 1.0 / fps

    def omega(t_s: np.ndarray, seed: int, amplitude_radps: float) -> np.ndarray:
        wy = reach_px / f_px * 2 * np.pi / period * np.cos(2 * np.pi * t_s / period)
        wx = np.full_like(t_s, drift_px / f_px / (period / 2))
        return np.stack([wx, wy, 0.0 * t_s], axis=1)

    return omega


@pytest.fixture(scope="module")
def hairpin_session(tmp_path_factory: pytest.TempPathFactory):
    from blurtrack.testing import mini_session

    fps, w = 25.0, 320
    folder = tmp_path_factory.mktemp("hairpins") / "s"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mini_session, "shake", _hairpin_shake(fps, 14.0, 3.0, 0.9 * w))
        mini_session.write_synthetic_session(
            folder, n_frames=4, seed=5, fps=fps, exposure_s=0.5 / fps, sigma_px=1.3
        )
    return load_session(folder)


def test_the_gyro_template_pass_in_workers_gives_the_same_table(hairpin_session) -> None:
    from blurtrack.detect import DetectParams

    kw = dict(gyro="on", refine_timeshift=False)
    one = detect_session(hairpin_session, workers=1, **kw)
    assert one.summary["gyro_template_frames"] == {"refined": 4}  # the pass changes frames
    for workers in (2, 3):
        other = detect_session(hairpin_session, workers=workers, **kw)
        pd.testing.assert_frame_equal(one.table, other.table, check_exact=True)
        assert one.summary == other.summary
    part = detect_session(hairpin_session, workers=2, frames=range(1, 3), **kw)
    pd.testing.assert_frame_equal(
        part.table,
        detect_session(hairpin_session, workers=1, frames=range(1, 3), **kw).table,
        check_exact=True,
    )
    # Negative control: the comparison sees the pass (the table without it differs).
    without = detect_session(hairpin_session, DetectParams(gyro_template=False), workers=2, **kw)
    assert without.summary["gyro_template_frames"] == {}
    with pytest.raises(AssertionError):
        pd.testing.assert_frame_equal(one.table, without.table, check_exact=True)


def test_fork_map_keeps_order_and_runs_closures() -> None:
    from blurtrack.detect import forkmap

    offset = 10  # a closure: inherited by the forked workers, never pickled
    items = list(range(7))
    for workers in (1, 2, 3):
        for chunk in (1, 3):
            got = list(forkmap.fork_map(lambda i: (i + offset, i * i), items, workers, chunk))
            assert got == [(i + offset, i * i) for i in items]
    assert list(forkmap.fork_map(lambda i: i, [], 2)) == []
    with pytest.raises(DetectionError, match="workers"):
        next(forkmap.fork_map(lambda i: i, items, 0))
    outer = forkmap.fork_map(lambda i: i, items, 2)
    assert next(outer) == 0
    with pytest.raises(DetectionError, match="already running"):
        next(forkmap.fork_map(lambda i: i, items, 2))
    assert list(outer) == items[1:]
    assert not forkmap._WORKER_STATE


def test_fork_map_runs_side_jobs_in_the_pool_ahead_of_the_items() -> None:
    import os

    from blurtrack.detect import forkmap

    here = os.getpid()
    base = [3, 4]  # closures over this process's state, as the mapped function
    for workers in (1, 2, 3):
        for n_items in (0, 1, 5):
            jobs = forkmap.Jobs(
                [lambda: (sum(base), os.getpid()), lambda: (base[0] * base[1], os.getpid())]
            )
            got = list(
                forkmap.fork_map(lambda i: i * i, list(range(n_items)), workers, 1, None, jobs)
            )
            assert got == [i * i for i in range(n_items)]
            assert [r[0] for r in jobs.results] == [7, 12]
            # computed by the workers where there are any, here otherwise
            in_here = [r[1] == here for r in jobs.results]
            assert all(in_here) if workers == 1 else not any(in_here)
    # the results are there once the first item is
    jobs = forkmap.Jobs([lambda: "a", lambda: "b"])
    it = forkmap.fork_map(lambda i: i, [0, 1], 2, 1, None, jobs)
    assert jobs.results == []
    assert next(it) == 0 and jobs.results == ["a", "b"]
    assert list(it) == [1]
    assert not forkmap._WORKER_STATE

    # A job's error reaches the caller, in a worker as here, and the map's state is cleared.
    def broken() -> None:
        raise ValueError("job failed")

    for workers in (1, 2):
        with pytest.raises(ValueError, match="job failed"):
            list(forkmap.fork_map(lambda i: i, [0, 1], workers, 1, None, forkmap.Jobs([broken])))
        assert not forkmap._WORKER_STATE


def _count_cue_calls(
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[list[tuple[list[int], list, tuple]], list[tuple[Any, tuple, list]]]:
    """Record the ids of the frame objects computed, the result and the arguments of every
    gyro-cue call in this process; and the first pass's cue jobs with their arguments and
    the cues of one call on them."""
    from blurtrack.detect.session import cues as detect_session_module

    calls: list[tuple[list[int], list, tuple]] = []
    jobs: list[tuple[Any, tuple, list]] = []
    real = detect_session_module.gyro_llrs
    real_jobs = detect_session_module.cue_jobs

    def spy(found, timings, covered, *a, **k):
        out = real(found, timings, covered, *a, **k)
        calls.append(([id(found[j]) for j in covered], out, (found, timings, covered, *a)))
        return out

    def spy_jobs(*a):
        # (with the cues of one batched call of these frames as they are now: the session
        # turns some of their streaks round at the end)
        out = real_jobs(*a)
        jobs.append((out, a, real(*a)))
        return out

    monkeypatch.setattr(detect_session_module, "gyro_llrs", spy)
    monkeypatch.setattr(detect_session_module, "cue_jobs", spy_jobs)
    return calls, jobs


def test_gyro_cues_computed_while_the_template_pass_runs(
    session_folder: Path, hairpin_session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The gyro cues of the first pass are computed batch by batch by the template pass's
    workers, ahead of its frames (with one worker: here, before it); afterwards only the
    frames the pass replaced are computed again: the same table as one process both where
    nothing and where every frame changed."""
    from blurtrack.detect.session.cues import gyro_llrs as real_llrs

    session = load_session(session_folder)
    one = detect_session(session, workers=1)
    calls, jobs = _count_cue_calls(monkeypatch)
    two = detect_session(session, workers=2)
    assert two.summary["gyro_template_frames"] == {"skipped": 5}
    assert calls == []  # none here: all from the workers' jobs, and kept
    pd.testing.assert_frame_equal(one.table, two.table, check_exact=True)
    # The jobs' results are the cues of one batched call in this process, batch by batch.
    (job, args, want), *_ = jobs
    got = [part for batch in job.results for part in batch]
    assert len(got) == len(want) == len(args[2])
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
    # A frame's cues depend on that frame alone: a subset's are the whole batch's rows.
    found, timings, covered, *rest = args
    whole = real_llrs(found, timings, covered, *rest)
    part = real_llrs(found, timings, covered[1:3], *rest)
    for g, w in zip(part, whole[1:3], strict=True):
        np.testing.assert_array_equal(g, w)
    # Frames the pass changes: those (and only those) computed again, as in one process.
    kw = dict(gyro="on", refine_timeshift=False)
    calls.clear()
    jobs.clear()
    two = detect_session(hairpin_session, workers=2, **kw)
    assert two.summary["gyro_template_frames"] == {"refined": 4}
    assert len(calls) == 1 and len(calls[0][0]) == 4
    first = [part for batch in jobs[0][0].results for part in batch]
    assert len(first) == 4
    # Negative control: the first pass's cues are not those of the refined frames.
    assert any(
        a is None or b is None or a.shape != b.shape or not np.array_equal(a, b)
        for a, b in zip(first, calls[0][1], strict=True)
    )
    calls.clear()
    ref = detect_session(hairpin_session, workers=1, **kw)
    assert len(calls) == 1 and len(calls[0][0]) == 4  # one worker: the same call
    pd.testing.assert_frame_equal(ref.table, two.table, check_exact=True)


def test_failed_cue_jobs_fall_back_as_the_one_call_does(monkeypatch: pytest.MonkeyPatch) -> None:
    """A batch that meets a coverage error: every frame computed on its own (a frame the
    gyro does not cover gets None), as :func:`gyro_llrs` does; another detection error:
    nothing (computed after the pass); otherwise the batches' cues in order."""
    from blurtrack.detect import forkmap
    from blurtrack.detect.session import cues as m

    frames: list[Any] = [[0.0] * 2, [], [0.0] * 3]
    covered = [0, 1, 2]
    batches = [[0], [2]]  # the frame without streaks is in no batch
    monkeypatch.setattr(m, "gyro_cue_batches", lambda sub: batches)

    def results(*rs: Any) -> forkmap.Jobs:
        jobs = forkmap.Jobs([])
        jobs.results = list(rs)
        return jobs

    ok = [[np.ones((2, 2))], [np.full((3, 2), 2.0)]]
    got = m.cues_of_jobs(results(*ok), frames, [], covered, None, None)
    assert [g.tolist() for g in got] == [[[1, 1]] * 2, [], [[2, 2]] * 3]
    assert got[1].shape == (0, 2)
    seen: list[list[int]] = []

    def by_frame(found, timings, cov, model, errors):
        seen.append(list(cov))
        return [None, np.zeros((0, 2)), np.zeros((3, 2))]

    monkeypatch.setattr(m, "gyro_llrs", by_frame)
    got = m.cues_of_jobs(results(ok[0], CoverageError("x")), frames, [], covered, None, None)
    assert seen == [covered] and got[0] is None
    assert (
        m.cues_of_jobs(results(DetectionError("y"), ok[1]), frames, [], covered, None, None) is None
    )
    # the first failure decides, in order: as the batches of one call meet them
    seen.clear()
    assert (
        m.cues_of_jobs(
            results(DetectionError("y"), CoverageError("x")), frames, [], covered, None, None
        )
        is None
    )
    assert seen == []


def test_recomputed_where_changed_keeps_the_rest() -> None:

    from blurtrack.detect.session import cues as m

    a, b, c = [1.0], [2.0], [3.0]
    first: list[Any] = [a, b, c]
    cues: list[Any] = [np.zeros((1, 2)), np.ones((1, 2))]  # covered: positions 0 and 2
    assert m.recomputed_where_changed(cues, first, [a, b, c], [], [0, 2], None, 0.1) is cues
    seen: list[list[int]] = []

    def fake(found, timings, covered, model, sigma_rel):
        seen.append(list(covered))
        return [np.full((1, 2), 7.0) for _ in covered]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(m, "gyro_llrs", fake)
        out = m.recomputed_where_changed(cues, first, [a, b, [3.0]], [], [0, 2], None, 0.1)
    assert seen == [[2]]  # an equal replacement is a change; only it is computed
    assert out[0] is cues[0] and out[1].tolist() == [[7.0, 7.0]]


def test_the_gyro_check_in_workers_is_that_of_one_process(
    session_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check's predictions, batch by batch in forked workers (batches of a few streaks
    here, so that there are many), give the very quality columns and count of one process,
    and the batches' curves are those of the one batched call per batch that
    ``predicted_curves`` makes; its ``meanwhile`` runs once, in this process."""
    import copy
    import dataclasses
    from functools import partial

    from blurtrack.detect.gyro import gyrostages as m
    from blurtrack.detect.gyro import gyrotrust

    inputs: list[tuple] = []
    real = m.check_frames

    def spy(found, timings, covered, model, p, *a, **k):
        inputs.append((copy.deepcopy(found), timings, covered, model, p))
        return real(found, timings, covered, model, p, *a, **k)

    monkeypatch.setattr(m, "check_frames", spy)
    detect_session(load_session(session_folder), workers=1)
    found, timings, covered, model, p = inputs[0]
    # Tolerances that this session's streaks fail in part: the check has something to do.
    p = dataclasses.replace(
        p, gyro_vector_tol_px=0.05, gyro_confirm_tol_px=0.05, hairpin_depth_px=0.01
    )
    frames = [found[k] for k in covered]
    assert len(gyrotrust._batches(frames, 25)) >= 4
    out = {}
    for workers in (1, 2, 3):
        fr = copy.deepcopy(found)
        calls: list[int] = []
        n = gyrotrust.check_frames(
            fr,
            timings,
            covered,
            model,
            p,
            workers,
            meanwhile=partial(calls.append, 1),
            batch_streaks=25,
        )
        assert calls == [1]
        out[workers] = (n, [fs.quality for fs in fr])
    assert out[1][0] == len(covered) > 0
    demoted = sum(
        int(np.sum(np.asarray(a.quality[2]) & ~np.asarray(q[2])))
        for a, q in zip(found, out[1][1], strict=True)
    )
    assert 0 < demoted < sum(int(np.sum(fs.quality[2])) for fs in found)
    for workers in (2, 3):
        assert out[workers][0] == out[1][0]
        for a, b in zip(out[1][1], out[workers][1], strict=True):
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y)
    # The batches' curves are those of predicted_curves (one model call per batch).
    tim = [timings[k] for k in covered]
    whole = gyrotrust.predicted_curves(frames, tim, model)
    for group in gyrotrust._batches(frames, 25):
        got = gyrotrust._vectors_of_batch(frames, tim, model, group, depth=True)
        for k, g in zip(group, got, strict=True):
            c = whole[k]
            assert c is not None and g is not None
            np.testing.assert_array_equal(g[0], c[:, -1] - c[:, 0])
            np.testing.assert_array_equal(g[1], gyrotrust.hairpin_depth(c))


def test_the_gyro_check_with_the_gates_curves_is_that_of_its_own_predictions(
    session_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The template pass hands the check its gate's curves of the frames it left as they
    were (the same model, PATH_SAMPLES): the check predicts only the clipped streaks of those
    and gives the quality columns and count it gives predicting every streak itself."""
    import copy
    import dataclasses

    from blurtrack.detect.gyro import gyrostages as m
    from blurtrack.detect.gyro import gyrotrust

    inputs: list[tuple] = []
    real = m.check_frames

    def spy(found, timings, covered, model, p, *a, **k):
        inputs.append((copy.deepcopy(found), timings, covered, model, p, k["known"]))
        return real(found, timings, covered, model, p, *a, **k)

    monkeypatch.setattr(m, "check_frames", spy)
    detect_session(load_session(session_folder), workers=1)
    found, timings, covered, model, p, known = inputs[0]
    assert set(known) <= set(covered) and len(known) > 0
    for k, c in known.items():
        assert c.shape == (int(np.sum(~found[k].flags["clipped"])), gyrotrust.PATH_SAMPLES, 2)
    # Tolerances that this session's streaks fail in part: the check has something to do.
    p = dataclasses.replace(
        p, gyro_vector_tol_px=0.05, gyro_confirm_tol_px=0.05, hairpin_depth_px=0.01
    )
    out = {}
    for name, given in (("own", None), ("known", known)):
        fr = copy.deepcopy(found)
        n = gyrotrust.check_frames(fr, timings, covered, model, p, 2, known=given)
        out[name] = (n, [fs.quality for fs in fr])
    assert out["own"][0] == out["known"][0] > 0
    for a, b in zip(out["own"][1], out["known"][1], strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    # Without workers too, and only the pending streaks are predicted.
    predicted: list[int] = []
    real_batch = gyrotrust._predicted_batch

    def counting(frames, tim, model_, group, samples):
        if samples == gyrotrust.PATH_SAMPLES:
            predicted.append(sum(len(frames[k]) for k in group))
        return real_batch(frames, tim, model_, group, samples)

    monkeypatch.setattr(gyrotrust, "_predicted_batch", counting)
    fr = copy.deepcopy(found)
    assert gyrotrust.check_frames(fr, timings, covered, model, p, 1, known=known) == out["own"][0]
    clipped_known = sum(int(np.sum(found[k].flags["clipped"])) for k in known)
    others = sum(len(found[k]) for k in covered if k not in known)
    assert sum(predicted) == clipped_known + others


def test_path_batches_are_the_batches_where_every_streak_is_pending() -> None:
    from blurtrack.detect.gyro import gyrotrust

    class F:
        def __init__(self, n: int) -> None:
            self.n = n
            self.time_mid = np.zeros((n, 2))

        def __len__(self) -> int:
            return self.n

    frames = [F(n) for n in (3000, 0, 900, 200, 4500, 10)]
    pending = [gyrotrust._Pending(f.time_mid) for f in frames]
    assert gyrotrust._path_batches(frames, pending) == gyrotrust._batches(frames)  # type: ignore[arg-type]
    assert gyrotrust._batches(frames) == [[0, 2], [3], [4], [5]]  # type: ignore[arg-type]
    # A frame with nothing pending still joins a batch (its depth), at an eighth of its size.
    pending[4] = gyrotrust._Pending(np.zeros((0, 2)))
    assert gyrotrust._path_batches(frames, pending) == [[0, 2], [3, 4, 5]]  # type: ignore[arg-type]


def test_one_blas_thread_within_and_as_it_was_after() -> None:
    from blurtrack.detect import forkmap

    fns = forkmap._openblas()
    if fns is None:
        pytest.skip("numpy is not linked against OpenBLAS here")
    get, put = fns
    before = int(get())
    put(2)  # (OpenBLAS may cap it at the cores it has)
    outside = int(get())
    try:
        with forkmap.one_blas_thread():
            assert int(get()) == 1
            # the workers forked within inherit it
            assert list(forkmap.fork_map(lambda _: int(get()), [0, 1], 2)) == [1, 1]
        assert int(get()) == outside
    finally:
        put(before)


def test_a_session_fitted_model_is_tested_as_it_is(
    session_folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the session calibration fitted the model over the first pass's streaks and the
    template pass changed no frame, the check fits nothing again: every quality_ok streak is
    tested against that model's own predicted vector (derived here from the model)."""
    import copy
    import dataclasses

    from blurtrack.detect.gyro import gyrostages as m
    from blurtrack.detect.gyro import gyrotrust
    from blurtrack.detect.gyro.gyrocurve import predict_curves

    inputs: list[tuple] = []
    real = m.check_frames

    def spy(found, timings, covered, model, p, *a, **k):
        inputs.append((copy.deepcopy(found), timings, covered, model, p, k.get("fitted")))
        return real(found, timings, covered, model, p, *a, **k)

    monkeypatch.setattr(m, "check_frames", spy)
    res = detect_session(load_session(session_folder), workers=1)
    assert res.summary["gyro_session_calibration"]["status"] == "fitted"
    assert not res.summary["gyro_template_frames"].get("refined")
    found, timings, covered, model, p, fitted = inputs[0]
    assert fitted is True

    def no_fit(*a, **k):
        raise AssertionError("the check fitted the session again")

    monkeypatch.setattr(gyrotrust, "session_fit", no_fit)
    tol = 0.3  # that this session's streaks fail in part
    p = dataclasses.replace(
        p, gyro_vector_tol_px=tol, gyro_confirm_tol_px=tol, hairpin_depth_px=1e3
    )
    fr = copy.deepcopy(found)
    gyrotrust.check_frames(fr, timings, covered, model, p, 1, fitted=True)
    demoted = 0
    for k in covered:
        before, after = found[k], fr[k]
        ok0 = np.asarray(before.quality[2], bool)
        t = timings[k]
        pts = predict_curves(model, before.time_mid, t.t_s, t.exposure_s, 2).pts
        v = pts[:, -1] - pts[:, 0]
        mv = before.end_b - before.end_a
        r = np.minimum(np.hypot(*(mv - v).T), np.hypot(*(mv + v).T))
        np.testing.assert_array_equal(ok0 & ~np.asarray(after.quality[2], bool), ok0 & (r > tol))
        demoted += int(np.sum(ok0 & (r > tol)))
    assert demoted > 0


def test_a_red_laser_session_says_its_frames_were_measured_on_the_lights_luma(
    session_folder: Path, tmp_path: Path, capsys
) -> None:
    import shutil

    folder = tmp_path / "red"
    shutil.copytree(session_folder, folder)
    # A red laser on a colour sensor: the green and blue channels see 0.18 and 0.06 of it.
    _rewrite_frames(
        folder,
        lambda k, img: np.dstack([img * 0.06, img * 0.18, img]).round().astype(np.uint8),
    )
    s = detect_session(load_session(folder), gyro="off", refine_timeshift=False).summary
    assert s["light_colour"]["frames"] == list(range(len(load_session(folder).frames)))
    np.testing.assert_allclose(s["light_colour"]["bgr"], [0.06, 0.18, 1.0], atol=0.03)
    assert main(["detect", str(folder), "--out", str(tmp_path / "r.parquet"), "--gyro", "off"]) == 0
    assert "frames measured on the luma of their one-colour light" in capsys.readouterr().out
    # Gray frames: none.
    gray = detect_session(load_session(session_folder), gyro="off", refine_timeshift=False)
    assert gray.summary["light_colour"] == {"frames": [], "bgr": None}
