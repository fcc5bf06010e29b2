"""The gyro's direction of motion checked against the frames' own continuity."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml

from blurtrack.cli import main
from blurtrack.detect.gyro.direction import (
    DECIDE_SIGMAS,
    MIN_PAIRS,
    direction_status,
    gyro_direction,
    sampled_frames,
    session_below,
)
from blurtrack.detect.params import DetectParams
from blurtrack.detect.session.orientation import CUE_SUBSTEP_S, CueErrors, FrameTiming
from blurtrack.detect.session.pipeline import detect_frames, detect_session
from blurtrack.errors import DetectionError
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session

#: A half turn about the optical axis: the x and y rates' signs swapped (the pan and tilt of
#: every streak reversed, its shape the same).
HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0, 1.0])


def with_axes(folder: Path, T: np.ndarray, axes_known: bool = True) -> None:
    """Rewrite the session's guessed camera-IMU transform (turned by ``T``)."""
    meta_path = folder / "session.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    meta["imu"]["T_cam_imu"] = (T @ np.array(meta["imu"]["T_cam_imu"])).tolist()
    meta["imu"]["axes_known"] = axes_known
    meta_path.write_text(yaml.safe_dump(meta))


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("direction")
    out: dict[str, Any] = {}
    for name in ("right", "half_turn"):
        folder = root / name
        out["truth"] = write_synthetic_session(
            folder, n_frames=8, seed=5, grid=(8, 6), amplitude_radps=3.0
        )
        if name == "half_turn":
            with_axes(folder, HALF_TURN_Z)
        out[name] = folder
    out["right_guess"] = root / "right_guess"
    shutil.copytree(out["right"], out["right_guess"])
    with_axes(out["right_guess"], np.eye(4), axes_known=False)
    return out


def starts_right(table: Any, truth: dict[str, Any]) -> float:
    """Fraction of the table's confidently oriented ``quality_ok`` streaks whose start is the
    nearest true streak's start (of those whose ends the truth tells apart)."""
    right = total = 0
    for fr in truth["frames"]:
        keep = table["quality_ok"] & (table["orientation_confidence"] >= 0.95)
        rows = table[(table["frame"] == fr["index"]) & keep]
        S = np.array([s["start"] for s in fr["streaks"]])
        E = np.array([s["end"] for s in fr["streaks"]])
        for s0, s1, e0, e1 in rows[["start_x", "start_y", "end_x", "end_y"]].to_numpy():
            d_same = np.hypot(*(S - [s0, s1]).T) + np.hypot(*(E - [e0, e1]).T)
            d_swap = np.hypot(*(S - [e0, e1]).T) + np.hypot(*(E - [s0, s1]).T)
            j = int(np.argmin(np.minimum(d_same, d_swap)))
            if abs(d_same[j] - d_swap[j]) < 2.0:
                continue  # the true streak too short to tell its ends apart
            right += int(d_same[j] < d_swap[j])
            total += 1
    return right / total


def test_right_axes_are_consistent_and_the_gyro_orients(sessions: dict[str, Any]) -> None:
    session = load_session(sessions["right"])
    res = detect_session(session, workers=1)
    d = res.summary["gyro_direction"]
    assert d["status"] == "consistent" and d["agree"] >= 0.8 * d["decisive"] > 60
    assert res.summary["orientation_sources"].get("gyro", 0) > 0.8 * len(res.table)
    assert starts_right(res.table, sessions["truth"]) > 0.97
    # axes marked a guess: confirmed by the images, the gyro is used all the same
    guess = detect_session(load_session(sessions["right_guess"]), workers=1)
    assert guess.summary["gyro_direction"]["status"] == "consistent"
    pd.testing.assert_frame_equal(guess.table, res.table)


def test_half_turned_axes_are_contradicted_and_the_images_orient(
    sessions: dict[str, Any],
) -> None:
    session = load_session(sessions["half_turn"])
    res = detect_session(session, workers=1)
    d = res.summary["gyro_direction"]
    assert d["status"] == "contradicted" and d["agree"] < 0.2 * d["decisive"]
    assert "R_cam_imu" in d["message"] and d["frames_contradicted"]
    assert "gyro" not in res.summary["orientation_sources"]
    assert res.summary["gyro_trust_frames"] == 0 and res.summary["frames_without_gyro"] == []
    # by continuity alone (21 ms gaps of a 3 rad/s shake: not as sure as the right gyro)
    assert starts_right(res.table, sessions["truth"]) > 0.8
    # negative control: without the check the gyro names the wrong end the start
    p = DetectParams.from_dict({"orientation": {"direction_check": False}})
    unchecked = detect_session(session, p, workers=1)
    assert unchecked.summary["gyro_direction"] is None
    assert starts_right(unchecked.table, sessions["truth"]) < 0.1
    with pytest.raises(DetectionError, match="runs against the images.*--gyro on stops"):
        detect_session(session, gyro="on", workers=1)


def test_the_check_beside_the_session_fit_gives_one_process_result(
    sessions: dict[str, Any],
) -> None:
    # With workers the direction is checked in a forked process while this one fits the
    # session calibration, which is dropped where the direction sets the gyro aside (the
    # right axes' case, the fit kept: test_detect_workers.py).
    session = load_session(sessions["half_turn"])
    one = detect_session(session, workers=1)
    two = detect_session(session, workers=2)
    pd.testing.assert_frame_equal(one.table, two.table, check_exact=True)
    assert one.summary == two.summary
    assert two.summary["gyro_session_calibration"] is None
    assert two.summary["gyro_direction"]["status"] == "contradicted"
    with pytest.raises(DetectionError, match="runs against the images.*--gyro on stops"):
        detect_session(session, gyro="on", workers=2)


def test_a_gyro_reading_zero_leaves_the_direction_undetermined(sessions: dict[str, Any]) -> None:
    session = load_session(sessions["right"])
    p = DetectParams()
    idx = list(range(len(session.frames)))
    found = list(detect_frames(session, idx, p, 1, None))
    timings = [FrameTiming(float(session.frame_times_s[i]), 0.012) for i in idx]
    t = np.arange(-0.1, 0.5, 1e-3)
    still = BlurModel(
        session.initial_calibration(),
        GyroTrace(t, np.zeros((t.size, 3))),
        max_substep_s=CUE_SUBSTEP_S,
        gyro_upsample=1,
    )
    got = gyro_direction(found, timings, idx, still, CueErrors(), p.orientation)
    assert got.status == "undetermined" and got.usable and got.decisive == 0
    # where the session's axes are a guess, a direction the images cannot confirm is not used
    guess = gyro_direction(found, timings, idx, still, CueErrors(), p.orientation, False)
    assert guess.status == "unconfirmed" and not guess.usable
    assert "axes_known: false" in guess.message(idx)
    assert gyro_direction(found, timings, [], still, CueErrors(), p.orientation).status == (
        "undetermined"
    )


def test_sampled_frames_spread_over_the_session() -> None:
    assert sampled_frames([3, 4, 5], 16) == [3, 4, 5]
    got = sampled_frames(list(range(100)), 5)
    assert got == [0, 25, 50, 74, 99]
    assert sampled_frames(list(range(10, 40)), 1) == [10]


def test_a_session_below_half_by_more_than_chance_is_known_values() -> None:
    # 50 % - 150 % / sqrt(n): 30.6 % at 60 pairs, 40.1 % at 230
    assert session_below(18, 60, 0.5) and not session_below(19, 60, 0.5)
    assert session_below(92, 230, 0.5) and not session_below(93, 230, 0.5)
    assert not session_below(113, 230, 0.5)  # hard_long_dense_grid 103: chance, not reversal
    assert session_below(9, 2260, 0.5)  # a half turn: 0.4 %
    assert not session_below(0, 0, 0.5)


def test_the_status_of_a_sample() -> None:
    o = DetectParams().orientation
    assert direction_status(2250, 2260, False, o, True) == "consistent"
    assert direction_status(9, 2260, False, o, True) == "contradicted"
    assert direction_status(120, 230, False, o, True) == "consistent"  # 52 %
    # below half, as chance would be: the images do not decide
    assert direction_status(113, 230, False, o, True) == "undetermined"
    assert direction_status(113, 230, False, o, False) == "unconfirmed"
    # one sampled frame against the gyro decides, whatever the sample says
    assert direction_status(2250, 2260, True, o, True) == "contradicted"
    # too few pairs
    few = 2 * MIN_PAIRS - 1
    assert direction_status(few, few, False, o, True) == "undetermined"
    assert direction_status(few, few, False, o, False) == "unconfirmed"


def test_a_gyro_at_chance_is_seldom_called_contradicted() -> None:
    """Property: samples whose agreement is a fair coin (continuity that reads nothing) are
    called contradicted at the one-sided tail's rate beyond DECIDE_SIGMAS, not half the time
    as a plain cut at 50 % would call them (the negative control)."""
    rng = np.random.default_rng(7)
    o = DetectParams().orientation
    n = rng.integers(2 * MIN_PAIRS, 3000, size=20000)
    agree = rng.binomial(n, 0.5)
    called = np.array(
        [
            direction_status(int(a), int(k), False, o, True) == "contradicted"
            for a, k in zip(agree, n, strict=True)
        ]
    )
    plain = agree < 0.5 * n
    assert DECIDE_SIGMAS == 3.0
    assert called.mean() < 0.004  # 0.13 % expected
    assert plain.mean() > 0.45
    # and a reversed axis set (agreement at most 13 %) is always called contradicted
    rev = rng.binomial(n, 0.13)
    assert all(
        direction_status(int(a), int(k), False, o, True) == "contradicted"
        for a, k in zip(rev, n, strict=True)
    )


def test_the_agreement_thresholds_are_ordered() -> None:
    with pytest.raises(Exception, match="direction_frame_agree must not exceed"):
        DetectParams.from_dict(
            {"orientation": {"direction_frame_agree": 0.6, "direction_session_agree": 0.5}}
        )


def test_the_command_says_why_and_gyro_on_stops(
    sessions: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    folder = sessions["half_turn"]
    out = tmp_path / "s.parquet"
    assert main(["detect", str(folder), "--out", str(out), "--workers", "1"]) == 0
    got = capsys.readouterr()
    err = got.err
    (line,) = [ln for ln in err.splitlines() if "runs against the images" in ln]
    assert line.startswith("  warning: ") and "detection used the images alone" in line
    # and quality_ok is the images' alone, which the note says as for --gyro off
    assert "note: without a gyro: quality_ok comes from the images alone" in got.out
    written = list(tmp_path.iterdir())
    assert main(["detect", str(folder), "--out", str(tmp_path / "on.parquet"), "--gyro", "on"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gyro on stops" in err[0]
    assert sorted(tmp_path.iterdir()) == sorted(written)  # nothing written on refusal


class _LineMotion:
    """A stand-in blur model: every point moves along ``direction`` by ``offset(t)`` px (no
    readout), so its image velocity is ``offset'(t) direction``."""

    def __init__(self, offset: Any, direction: tuple[float, float] = (1.0, 0.0)) -> None:
        self.offset = offset
        self.direction = np.asarray(direction, float)
        self.camera = type("Cam", (), {"readout_s": 0.0, "height": 100})()

    def point_track(self, pixels: np.ndarray, t_ref: np.ndarray, times: np.ndarray) -> np.ndarray:
        shift = self.offset(times) - self.offset(np.asarray(t_ref)[:, None])
        return pixels[:, None, :] + shift[..., None] * self.direction

    point_track_ordered = point_track


@pytest.mark.parametrize("direction", [(1.0, 0.0), (-1.0, 0.0), (0.6, -0.8)])
def test_turns_within_an_exposure_or_in_a_gap_are_told_whichever_way_the_axes_are(
    direction: tuple[float, float],
) -> None:
    """Frames 0, 1, 2 of 20 ms every 33 ms: a motion that runs one way throughout turns
    nowhere; one that turns back in the middle of frame 1's exposure, or in the gap between
    frames 0 and 1, turns there; the same for the image velocity in any direction (an axis
    sign or order error maps every velocity alike)."""
    from blurtrack.detect.gyro.direction import _turning

    fs = type(
        "FS", (), {"time_mid": np.array([[20.0, 50.0], [60.0, 30.0]]), "__len__": lambda s: 2}
    )()
    timings = [FrameTiming(k / 30.0, 0.02) for k in range(3)]
    mid1 = timings[1].t_s + 0.01
    gap01 = 0.5 * (timings[0].t_s + 0.02 + timings[1].t_s)
    cases = {
        "straight": (lambda t: 300.0 * t, [False, False]),
        "turn in the exposure": (lambda t: -3000.0 * (t - mid1) ** 2, [True, True]),
        "turn in the gap": (lambda t: 300.0 * np.abs(t - gap01), [True, True]),
    }
    for name, (offset, expected) in cases.items():
        got = _turning(fs, 1, [0, 1, 2], timings, _LineMotion(offset, direction))
        assert got.tolist() == expected, name
    # Negative control: the gap turn is not in frame 1's own exposure, nor in its gap to
    # frame 2, so with only that neighbour nothing turns.
    offset = cases["turn in the gap"][0]
    assert _turning(fs, 1, [1, 2], timings, _LineMotion(offset, direction)).tolist() == [False] * 2


class _ArcMotion:
    """A stand-in blur model: every point moves on a circle of ``radius_px``, its angle
    ``rate * (t - t0)`` (no readout), the image motion then mapped by ``M`` (an error of the
    axes' signs or order maps every velocity alike)."""

    def __init__(self, rate: float, t0: float, M: np.ndarray, radius_px: float = 20.0) -> None:
        self.rate, self.t0, self.M, self.radius = rate, t0, M, radius_px
        self.camera = type("Cam", (), {"readout_s": 0.0, "height": 100})()

    def _at(self, t: np.ndarray) -> np.ndarray:
        a = self.rate * (np.asarray(t, float) - self.t0)
        return self.radius * np.stack([np.cos(a), np.sin(a)], axis=-1) @ self.M.T

    def point_track(self, pixels: np.ndarray, t_ref: np.ndarray, times: np.ndarray) -> np.ndarray:
        return pixels[:, None, :] + self._at(times) - self._at(np.asarray(t_ref))[:, None, :]

    point_track_ordered = point_track


@pytest.mark.parametrize(
    "M", [np.eye(2), np.array([[-1.0, 0.0], [0.0, 1.0]]), np.array([[0.0, -1.0], [1.0, 0.0]])]
)
def test_a_gradual_turn_back_within_the_exposure_is_a_turn(M: np.ndarray) -> None:
    """A dot whose velocity turns by 135 degrees over the exposure in even steps (17 degrees
    from one of the 9 samples to the next: no two successive steps at an obtuse angle) has
    turned back: its first and last velocities are; by 60 degrees it has not (the negative
    control). Frame 1 alone (no neighbour: no gap to read), any axis mapping ``M``."""
    from blurtrack.detect.gyro.direction import _turning

    fs = type(
        "FS", (), {"time_mid": np.array([[20.0, 50.0], [60.0, 30.0]]), "__len__": lambda s: 2}
    )()
    timings = [FrameTiming(k / 30.0, 0.02) for k in range(3)]
    t0 = timings[1].t_s
    for degrees, expected in ((135.0, True), (60.0, False)):
        motion = _ArcMotion(np.radians(degrees) / 0.02, t0, M)
        assert _turning(fs, 1, [1], timings, motion).tolist() == [expected] * 2, degrees
