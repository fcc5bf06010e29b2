"""Frame pairs on several threads (blurtrack.features.pairs): a plain loop's results in its
order, each frame read once per block, and the tracks independent of the thread count."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from blurtrack.features import pairs
from blurtrack.features.pairs import map_pairs
from blurtrack.features.tracks import track_frames
from tests.blurtrack.features.test_features_tracks import _shifted, _texture


def test_results_are_a_plain_loops_in_order(monkeypatch) -> None:
    monkeypatch.setattr(pairs, "BLOCK", 3)  # several blocks, frames carried across them
    frames = [np.full((2, 2), i * i) for i in range(12)]
    reads: list[int] = []
    lock = threading.Lock()

    def read(i: int) -> np.ndarray:
        with lock:
            reads.append(i)
        return frames[i]

    def fn(f: int, a: np.ndarray, b: np.ndarray) -> tuple[int, int]:
        return f, int(b[0, 0] - a[0, 0])

    firsts = [0, 1, 2, 4, 5, 9, 10]
    want = [(f, (f + 1) ** 2 - f * f) for f in firsts]
    for workers in (1, 2, 3):
        reads.clear()
        assert map_pairs(fn, read, firsts, workers) == want
        needed = sorted(set(firsts) | {f + 1 for f in firsts})
        assert sorted(reads) == needed
    done: list[tuple[int, int]] = []
    map_pairs(fn, read, firsts, 2, lambda k, n: done.append((k, n)))
    assert done == [(3, 7), (6, 7), (7, 7)]


def test_a_frame_shared_by_two_blocks_is_read_once(monkeypatch) -> None:
    monkeypatch.setattr(pairs, "BLOCK", 2)
    reads: list[int] = []
    map_pairs(lambda f, a, b: f, lambda i: reads.append(i) or np.zeros(1), range(6), 2)
    assert sorted(reads) == list(range(7))


def test_a_failed_read_stops_the_work_a_block_ahead_at_most(monkeypatch) -> None:
    """Frames are read one block ahead: a read error surfaces before later blocks are read
    (pairs [4, 5] need frames 4-6; nothing past block [4, 5] was asked for)."""
    monkeypatch.setattr(pairs, "BLOCK", 2)
    reads: list[int] = []
    lock = threading.Lock()

    def read(i: int) -> np.ndarray:
        with lock:
            reads.append(i)
        if i == 5:
            raise OSError("frame 5 unreadable")
        return np.zeros(1)

    with pytest.raises(OSError, match="frame 5"):
        map_pairs(lambda f, a, b: f, read, range(40), 2)
    assert 5 in reads and max(reads) <= 6


def test_bad_orders_and_worker_counts() -> None:
    with pytest.raises(ValueError, match="ascending"):
        map_pairs(lambda f, a, b: f, lambda i: np.zeros(1), [2, 1])
    with pytest.raises(ValueError, match="at least 1"):
        map_pairs(lambda f, a, b: f, lambda i: np.zeros(1), [0], workers=0)


def test_tracks_do_not_depend_on_the_thread_count() -> None:
    base = _texture(5)
    frames = [_shifted(base, 1.5 * i, -0.7 * i) for i in range(7)]
    one = track_frames(frames.__getitem__, 7, workers=1)
    two = track_frames(frames.__getitem__, 7, workers=2)
    for name in ("frame_a", "frame_b", "pts_a", "pts_b", "fb_error_px", "per_pair"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert len(one) > 100
    # a control that the comparison can fail: other frames give other tracks
    other = track_frames([_shifted(base, 1.4 * i, -0.7 * i) for i in range(7)].__getitem__, 7)
    assert not np.array_equal(one.pts_b, other.pts_b)
