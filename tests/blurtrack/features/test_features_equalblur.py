"""Equal-blur refinement (blurtrack.features.equalblur): kernels as filters, float
Lucas–Kanade, and the displacement of differently blurred frames recovered where plain
Lucas–Kanade is pulled along the blur difference (negative control)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blurtrack.features import equalblur
from blurtrack.features.equalblur import (
    equal_blur_patches,
    kernel_stack,
    lucas_kanade,
    refine_equal_blur,
    refine_patches,
)
from blurtrack.features.tracks import FeatureTrackError, track_pair


def _texture(seed: int, shape=(240, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 1, shape).astype(np.float32), (0, 0), 2.0)
    return (img - img.min()) / (img.max() - img.min())


def _shift(img: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``J(x) = img(x − d)``."""
    M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
    return cv2.warpAffine(
        img, M, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


def _path(v: np.ndarray, acc: np.ndarray, n: int = 64) -> np.ndarray:
    """Positions over an exposure relative to mid-exposure: ``v τ + a τ² / 2``, τ ∈ (−½, ½)."""
    tau = (np.arange(n) + 0.5) / n - 0.5
    return tau[:, None] * v[None, :] + 0.5 * tau[:, None] ** 2 * acc[None, :]


def _blurred(sharp: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """``I(x) = mean_k S(x − o_k)``: the scene seen along the point's exposure path."""
    return np.mean([_shift(sharp, o) for o in offsets], axis=0).astype(np.float32)


def test_kernel_stack_filter_is_the_mean_of_shifted_images() -> None:
    img = _texture(0)
    o = np.array([[[1.25, -0.5], [-2.0, 3.75], [0.0, 0.0]]])
    k = kernel_stack(o, 5)[0]
    assert k.shape == (11, 11) and k.sum() == pytest.approx(1.0, abs=1e-6)
    got = cv2.filter2D(img, -1, k)
    bilinear = [
        cv2.warpAffine(
            img, np.float32([[1, 0, x], [0, 1, y]]), img.shape[::-1], flags=cv2.INTER_LINEAR
        )
        for x, y in o[0]
    ]
    want = np.mean(bilinear, axis=0)
    inner = (slice(20, -20), slice(20, -20))
    assert np.max(np.abs(got[inner] - want[inner])) < 1e-5


def test_lucas_kanade_recovers_subpixel_translations() -> None:
    img = _texture(1)
    rng = np.random.default_rng(2)
    d = rng.uniform(-2.5, 2.5, (12, 2))
    c = rng.uniform(60, 180, (12, 2))
    moved = [_shift(img, di) for di in d]
    tpl = np.stack([cv2.getRectSubPix(img, (23, 23), tuple(ci)) for ci in c])
    tgt = np.stack(
        [cv2.getRectSubPix(m, (33, 33), tuple(ci)) for m, ci in zip(moved, c, strict=True)]
    )
    got, ok = lucas_kanade(tpl, tgt)
    assert ok.all()
    # bilinear interpolation: a few hundredths of pixel-locking (OpenCV: 0.025 median here)
    assert np.max(np.abs(got - d)) < 0.08 and np.median(np.abs(got - d)) < 0.04


def test_lucas_kanade_of_a_batch_is_each_track_alone() -> None:
    """Tracks converge after different numbers of iterations (the active set shrinks while
    mismatched ones run all iterations): each track's translation and flag equal those of
    the track refined alone, bit for bit, so sampling by active row picks the right patch."""
    img = _texture(3)
    rng = np.random.default_rng(4)
    n = 16
    d = rng.uniform(-2.5, 2.5, (n, 2))
    c = rng.uniform(60, 180, (n, 2))
    tpl = np.stack([cv2.getRectSubPix(img, (23, 23), tuple(ci)) for ci in c])
    tgt = np.stack(
        [
            cv2.getRectSubPix(_shift(img, di), (33, 33), tuple(ci))
            for di, ci in zip(d, c, strict=True)
        ]
    )
    tgt[::3] = tgt[::3][:, ::-1, ::-1]  # every third target mismatched: never converges
    got, ok = lucas_kanade(tpl, tgt, iterations=12)
    alone = [lucas_kanade(tpl[i : i + 1], tgt[i : i + 1], iterations=12) for i in range(n)]
    assert np.array_equal(got, np.concatenate([a[0] for a in alone]))
    assert np.array_equal(ok, np.concatenate([a[1] for a in alone]))
    assert 0 < ok.sum() < n  # both kinds present: the active set did shrink
    assert np.max(np.abs(got[ok] - d[ok])) < 0.08


def test_equal_blur_recovers_the_mid_exposure_displacement() -> None:
    """Frame a: slow motion; frame b: fast, accelerating motion in another direction. Plain
    LK (even with each end's blur centroid removed) errs along the blur difference; the
    equal-blur refinement recovers the displacement of the mid-exposure positions."""
    sharp = _texture(3)
    s = np.array([4.3, -2.6])  # mid-exposure displacement between the frames
    oa = _path(np.array([2.0, 1.0]), np.array([0.0, 3.0]))
    ob = _path(np.array([14.0, 5.0]), np.array([-10.0, 8.0]))
    img_a = _blurred(sharp, oa)
    img_b = _blurred(_shift(sharp, s), ob)
    pa, pb, _ = track_pair((img_a * 255).astype(np.uint8), (img_b * 255).astype(np.uint8))
    inside = np.all((pa > 40) & (pa < np.array([280, 200])), axis=1)
    pa, pb = pa[inside], pb[inside]
    assert len(pa) > 40
    centroid = ob.mean(axis=0) - oa.mean(axis=0)
    lk_err = np.linalg.norm(pb - pa - centroid - s, axis=1)  # centroid-corrected LK
    n = len(pa)
    ref, ok = refine_equal_blur(
        img_a,
        img_b,
        pa,
        pb,
        np.broadcast_to(oa, (n, *oa.shape)),
        np.broadcast_to(ob, (n, *ob.shape)),
    )
    assert ok.mean() > 0.9
    eb = ref[ok] - pa[ok] - s
    # measured: LK 1.7 px median (mostly along the blur difference), equal blur 0.05 px
    assert np.median(np.linalg.norm(eb, axis=1)) < 0.1
    assert np.all(np.abs(np.mean(eb, axis=0)) < 0.06)
    assert np.median(lk_err) > 0.5  # negative control
    assert np.median(lk_err) > 8 * np.median(np.linalg.norm(eb, axis=1))


def test_refinement_validates_shapes() -> None:
    img = _texture(4)
    with pytest.raises(FeatureTrackError, match="differ in shape"):
        refine_equal_blur(
            img, img, np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((2, 4, 2)), np.zeros((3, 4, 2))
        )
    with pytest.raises(FeatureTrackError, match="window_px"):
        refine_equal_blur(
            img,
            img,
            np.zeros((1, 2)),
            np.zeros((1, 2)),
            np.zeros((1, 4, 2)),
            np.zeros((1, 4, 2)),
            window_px=8,
        )
    out, ok = refine_equal_blur(
        img, img, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 4, 2)), np.zeros((0, 4, 2))
    )
    assert out.shape == (0, 2) and ok.shape == (0,)


def test_patches_of_several_pairs_refine_as_pair_by_pair(monkeypatch) -> None:
    """Lucas–Kanade on the concatenated patches of two frame pairs (how calib.natural.pipeline runs
    it) gives exactly the pair-by-pair refinement; a pair refined with the other pair's
    kernels does not (negative control: the comparison sees the kernels)."""
    sharp = _texture(5)
    rng = np.random.default_rng(7)
    pairs = []
    for k, (va, vb) in enumerate((([2.0, 1.0], [9.0, -4.0]), ([-6.0, 3.0], [1.0, 12.0]))):
        s = np.array([3.1, -1.7]) * (k + 1)
        oa, ob = _path(np.array(va), np.zeros(2)), _path(np.array(vb), np.array([2.0, 0.0]))
        img_a, img_b = _blurred(sharp, oa), _blurred(_shift(sharp, s), ob)
        pa = rng.uniform(50, 190, (25, 2))
        pb = pa + s + rng.normal(0, 0.5, pa.shape)
        n = len(pa)
        pairs.append(
            (
                img_a,
                img_b,
                pa,
                pb,
                np.broadcast_to(oa, (n, *oa.shape)),
                np.broadcast_to(ob, (n, *ob.shape)),
            )
        )
    one = [refine_equal_blur(*p) for p in pairs]
    patches = [equal_blur_patches(*p) for p in pairs]
    cat = [np.concatenate(c) for c in zip(*patches, strict=True)]
    pts, ok = refine_patches(np.concatenate([p[3] for p in pairs]), *cat)
    assert np.array_equal(pts, np.concatenate([o[0] for o in one]))
    assert np.array_equal(ok, np.concatenate([o[1] for o in one]))
    assert ok.mean() > 0.8
    # shared by threads in chunks (a chunk of 7 tracks here): the same again
    monkeypatch.setattr(equalblur, "MIN_CHUNK", 7)
    split = refine_patches(np.concatenate([p[3] for p in pairs]), *cat, workers=3)
    assert np.array_equal(split[0], pts) and np.array_equal(split[1], ok)
    swapped = refine_equal_blur(*pairs[0][:4], pairs[1][4], pairs[1][5])
    assert not np.array_equal(swapped[0], one[0][0])
    none2, none3 = np.zeros((0, 2)), np.zeros((0, 4, 2))
    empty = equal_blur_patches(*pairs[0][:2], none2, none2, none3, none3)
    assert refine_patches(none2, *empty)[0].shape == (0, 2)
