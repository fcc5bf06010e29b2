"""Feature tracks (blurtrack.features.tracks): sub-pixel shifts recovered, the
forward-backward check, frame conversion and parameter validation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.features.tracks import (
    FeatureTrackError,
    TrackParams,
    corners,
    to_gray8,
    track_frames,
    track_pair,
)


def _texture(seed: int, shape=(180, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, shape).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return img.astype(np.uint8)


def _shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(
        img, M, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


def test_track_pair_recovers_a_subpixel_shift() -> None:
    a = _texture(0)
    b = _shifted(a, 3.3, -1.7)
    pa, pb, fb = track_pair(a, b)
    assert len(pa) > 100
    d = np.median(pb - pa, axis=0)
    # LK interpolates bilinearly, the shift here is cubic: a few hundredths of pixel-locking.
    assert np.allclose(d, [3.3, -1.7], atol=0.06)
    assert np.all(fb < TrackParams().fb_max_px)


def test_corners_at_half_resolution_are_the_half_frames_corners_in_full_pixels() -> None:
    small = _texture(3, (120, 160))
    big = cv2.resize(small, (320, 240), interpolation=cv2.INTER_NEAREST)  # 2x2 blocks
    got = corners(big, TrackParams(min_distance_px=10, block_size=7, corner_downscale=2))
    # area averaging gives ``small`` back; its corners under the halved settings, mapped by
    # pixel centres: x_full + 0.5 = 2 (x_small + 0.5)
    ref = corners(small, TrackParams(corner_downscale=1, min_distance_px=5, block_size=5))
    assert len(got) > 50
    np.testing.assert_allclose(got, (ref + 0.5) * 2 - 0.5, atol=1e-5)
    # negative control: scaling the coordinates alone is half a pixel off
    assert np.abs(got - ref * 2).max() > 0.4
    # full resolution is another detector's answer, not a rescaled one
    full = corners(big, TrackParams(corner_downscale=1))
    assert full.shape != got.shape or not np.allclose(full, got)
    with pytest.raises(FeatureTrackError, match="corner_downscale"):
        TrackParams(corner_downscale=0)


def test_forward_backward_check_rejects_unrelated_frames() -> None:
    pa, _, _ = track_pair(_texture(1), _texture(2))
    pa_same, _, _ = track_pair(_texture(1), _shifted(_texture(1), 1.0, 1.0))
    assert len(pa) < 0.2 * len(pa_same)


def test_track_frames_reads_each_frame_and_labels_pairs() -> None:
    base = _texture(3)
    frames = [_shifted(base, 2.0 * i, 0.5 * i) for i in range(4)]
    reads: list[int] = []

    def read(i: int) -> np.ndarray:
        reads.append(i)
        return frames[i]

    tr = track_frames(read, 4)
    assert sorted(reads) == [0, 1, 2, 3]  # each frame once (threads: any order)
    assert tr.n_frames == 4 and tr.per_pair.shape == (3,)
    assert np.all(tr.frame_b == tr.frame_a + 1)
    assert np.allclose(np.median(tr.pts_b - tr.pts_a, axis=0), [2.0, 0.5], atol=0.06)
    with pytest.raises(FeatureTrackError, match="at least 2 frames"):
        track_frames(read, 1)


def test_to_gray8_and_params() -> None:
    g16 = np.arange(64, dtype=np.uint16).reshape(8, 8) * 1000
    assert to_gray8(g16).dtype == np.uint8 and to_gray8(g16).max() == 255
    bgr = np.dstack([_texture(4)] * 3)
    assert to_gray8(bgr).shape == bgr.shape[:2]
    with pytest.raises(FeatureTrackError):
        to_gray8(np.zeros((4, 4, 2), np.uint8))
    with pytest.raises(FeatureTrackError, match="window"):
        TrackParams(window_px=20)
    with pytest.raises(FeatureTrackError, match="differ in size"):
        track_pair(_texture(0), _texture(0, (90, 160)))


@pytest.mark.parametrize("max_side", [1280, 200])  # at full resolution and downscaled
def test_masked_rectangles_lose_their_tracks_and_nothing_else(max_side: int) -> None:
    a = _texture(3)
    b = _shifted(a, 2.0, 1.0)
    full = track_pair(a, b, TrackParams(max_side_px=max_side))
    rect = (0.0, 100.0, 319.0, 179.0)  # the bottom rows, as a dashboard
    pa, pb, fb = track_pair(a, b, TrackParams(max_side_px=max_side, exclude_px=(rect,)))
    hit = (full[0][:, 1] >= 100) | (full[1][:, 1] >= 100)
    assert 0 < len(pa) == np.count_nonzero(~hit) < len(full[0])  # a negative control: some hit
    np.testing.assert_array_equal(pa, full[0][~hit])
    np.testing.assert_array_equal(pb, full[1][~hit])
    np.testing.assert_array_equal(fb, full[2][~hit])


@pytest.mark.parametrize("rect", [(10, 10, 5, 20), (0, 0, 10, float("nan")), (1, 2, 3)])
def test_malformed_mask_rectangles_are_refused(rect: tuple) -> None:
    with pytest.raises(FeatureTrackError, match="masked rectangle"):
        TrackParams(exclude_px=(rect,))
