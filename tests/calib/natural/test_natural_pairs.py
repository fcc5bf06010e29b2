"""Tracking with each pair's rotation measured on its tracking thread (calib.natural.pairs)
gives exactly the tracks of track_frames and the rotations of image_rotations afterwards,
on a small simulated natural session; too few measured pairs are refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blurtrack.features.tracks import FeatureTrackError, TrackParams, track_frames, tracks_of_pairs
from blurtrack.io.session import load_session
from calib.axes.rotations import collect_rotations
from calib.errors import AxisSearchError
from calib.natural.pairs import track_and_rotate
from calib.natural.pipeline import image_rotations
from rigs.sim.natural import NaturalRig
from rigs.sim.preset import get_preset
from rigs.sim.writer import write_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    folder: Path = tmp_path_factory.mktemp("pairs") / "s"
    preset = get_preset("realistic").replace(width=320, height=180, focal_px=250.0)
    write_session(NaturalRig(preset, 3, 12), folder)
    return load_session(folder)


def test_tracks_and_rotations_equal_tracking_then_measuring(session) -> None:
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)
    ex = session.frames["exposure_ns"].to_numpy(np.int64)
    initial = session.initial_calibration()
    for workers in (1, 2):
        tracks, per_pair = track_and_rotate(
            session.read_image, ts, ex, initial, TrackParams(), workers=workers
        )
        ref = track_frames(session.read_image, ts.size, workers=workers)
        for name in ("frame_a", "frame_b", "pts_a", "pts_b", "fb_error_px", "per_pair"):
            assert np.array_equal(getattr(tracks, name), getattr(ref, name)), name
        assert tracks.n_frames == ref.n_frames == ts.size
        rots, want = collect_rotations(per_pair), image_rotations(ref, ts, ex, initial)
        assert len(rots) == len(want) >= 8
        for name in ("t_a_s", "t_b_s", "R_img", "n_points", "frame_a", "translating"):
            assert np.array_equal(getattr(rots, name), getattr(want, name)), name
    # a control the comparison can fail: other tracking settings give other tracks
    fewer, _ = track_and_rotate(session.read_image, ts, ex, initial, TrackParams(max_corners=50))
    assert len(fewer) < len(tracks)


def test_too_few_pairs_and_mismatched_pairs_are_refused(session) -> None:
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)[:3]
    ex = session.frames["exposure_ns"].to_numpy(np.int64)[:3]
    _, per_pair = track_and_rotate(
        session.read_image, ts, ex, session.initial_calibration(), TrackParams()
    )
    with pytest.raises(AxisSearchError, match="too few frame pairs"):
        collect_rotations(per_pair)
    with pytest.raises(FeatureTrackError, match="at least 2 frames"):
        track_and_rotate(
            session.read_image, ts[:1], ex[:1], session.initial_calibration(), TrackParams()
        )
    with pytest.raises(FeatureTrackError, match="2 frame pairs tracked for 4 frames"):
        tracks_of_pairs([(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))] * 2, 4)


def test_work_given_meanwhile_is_done_and_its_errors_left_for_later(session) -> None:
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)[:4]
    ex = session.frames["exposure_ns"].to_numpy(np.int64)[:4]
    ran: list[str] = []

    def fails() -> None:
        ran.append("fails")
        raise ValueError("met again later")

    tracks, _ = track_and_rotate(
        session.read_image,
        ts,
        ex,
        session.initial_calibration(),
        TrackParams(),
        meanwhile=[lambda: ran.append("ok"), fails],
    )
    assert sorted(ran) == ["fails", "ok"] and tracks.n_frames == 4
