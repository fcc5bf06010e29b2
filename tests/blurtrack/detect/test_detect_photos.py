"""Detection on still photographs (:mod:`blurtrack.detect.photos`) and the source picture
(:func:`blurtrack.detect.overlay.source_picture`): a photograph is one frame detected from its
image alone, the same streaks as :func:`~blurtrack.detect.frame.detect_frame`, unoriented."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from blurtrack.detect import DetectParams, detect_frame
from blurtrack.detect.overlay import SOURCE_COLOURS, source_picture
from blurtrack.detect.photos import detect_photos, is_photo
from blurtrack.detect.separation.quality import frame_quality
from blurtrack.io.images import ImageError
from blurtrack.testing.streak_frames import line_grid, quantise, render_streaks

SHAPE = (200, 300)
SIGMA = 1.5
#: A lit window (x0, y0, x1, y1) in the top left; the dots lie below it.
WINDOW = (20, 15, 70, 55)


def dots() -> list[np.ndarray]:
    """Ten dots' streaks, all the same 18 px line (their truth)."""
    return line_grid(10, 5, (30.0, 100.0), (50.0, 50.0), (16.0, 8.0))


def photo(window: bool = True, seed: int = 0) -> np.ndarray:
    """Full-scale float image: :func:`dots` and, with ``window``, a lit window blurred by
    the same spread."""
    img = render_streaks(SHAPE, dots(), 2.0, SIGMA, 0.03, 0.004, seed)
    if window:
        lit = np.zeros(SHAPE, np.float32)
        x0, y0, x1, y1 = WINDOW
        lit[y0:y1, x0:x1] = 0.6
        img = img + cv2.GaussianBlur(lit, (0, 0), SIGMA)
    return img


def write_photos(folder: Path) -> list[Path]:
    """An 8-bit gray PNG, a colour JPEG and a 16-bit PNG of :func:`photo` (seeds 0, 1, 2)."""
    folder.mkdir(parents=True, exist_ok=True)
    gray = folder / "gray.png"
    cv2.imwrite(str(gray), quantise(photo(seed=0), np.uint8))
    g = quantise(photo(seed=1), np.uint8)
    colour = folder / "colour.jpg"
    cv2.imwrite(str(colour), np.dstack([g // 3, g, g // 2]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    deep = folder / "deep.png"
    cv2.imwrite(str(deep), quantise(photo(seed=2), np.uint16))
    return [gray, colour, deep]


def near_a_dot(x: np.ndarray, y: np.ndarray, tol: float = 2.0) -> np.ndarray:
    """``(N,)`` whether each point lies within ``tol`` px of a dot's streak's start or end."""
    ends = np.array([c[i] for c in dots() for i in (0, -1)])
    d = np.hypot(x[:, None] - ends[None, :, 0], y[:, None] - ends[None, :, 1])
    return np.asarray(d.min(axis=1) <= tol)


def test_each_photograph_is_its_image_alone_unoriented(tmp_path: Path) -> None:
    paths = write_photos(tmp_path)
    got = detect_photos(paths)
    table = got.table
    assert sorted(set(table["frame"])) == [0, 1, 2]
    for k, path in enumerate(paths):
        rows = table[table["frame"] == k]
        fs = detect_frame(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
        # The same streaks as the frame's own detection, in its order, ends either way.
        assert len(rows) == len(fs) == got.photos[k]["streaks"]
        a = rows[["start_x", "start_y"]].to_numpy()
        np.testing.assert_array_equal(a, fs.end_a)
        assert got.photos[k]["photo"] == str(path)
        assert (got.photos[k]["height_px"], got.photos[k]["width_px"]) == SHAPE
        assert got.photos[k]["quality_ok"] == int(rows["quality_ok"].sum())
        assert sum(got.photos[k]["source"].values()) == len(rows)
    assert set(table["orientation_source"]) == {"none"}
    assert np.all(table["orientation_confidence"] == 0.5)
    # Two workers: the same table.
    pd.testing.assert_frame_equal(detect_photos(paths, workers=2).table, table)


def test_the_dots_are_ok_and_the_window_is_not(tmp_path: Path) -> None:
    got = detect_photos(write_photos(tmp_path))
    t = got.table
    ok = t[t["quality_ok"]]
    # Every quality_ok detection is a dot's whole streak (both ends within 2 px of its ends).
    assert len(ok) >= 3 * 8
    assert near_a_dot(ok["start_x"].to_numpy(), ok["start_y"].to_numpy()).all()
    assert near_a_dot(ok["end_x"].to_numpy(), ok["end_y"].to_numpy()).all()
    # The window: whatever is found there is neither ok nor a point light.
    x0, y0, x1, y1 = WINDOW
    mx, my = t["mid_x"].to_numpy(), t["mid_y"].to_numpy()
    inside = (mx > x0 - 6) & (mx < x1 + 6) & (my > y0 - 6) & (my < y1 + 6)
    assert inside.any()
    assert not t[inside]["quality_ok"].any()
    assert not (t[inside]["source"] == "point").any()
    # Negative control: without the window nothing is found there.
    img = quantise(photo(window=False), np.uint8)
    path = tmp_path / "dots_only.png"
    cv2.imwrite(str(path), img)
    t0 = detect_photos([path]).table
    assert not ((t0["mid_x"] < x1 + 6) & (t0["mid_y"] < y1 + 6)).any()


def test_a_photograph_that_does_not_decode_is_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8 not a jpeg")
    with pytest.raises(ImageError, match="bad.jpg"):
        detect_photos([bad])
    with pytest.raises(ImageError, match="not found"):
        detect_photos([tmp_path / "missing.png"])


def test_is_photo_by_suffix_not_folders(tmp_path: Path) -> None:
    assert is_photo("a.JPG") and is_photo("b.tiff") and is_photo(Path("c.png"))
    assert not is_photo("session") and not is_photo("x.parquet")
    folder = tmp_path / "odd.png"
    folder.mkdir()
    assert not is_photo(folder)


def test_the_source_picture_colours_each_detection_by_its_source(tmp_path: Path) -> None:
    paths = write_photos(tmp_path)
    t = detect_photos(paths[:1]).table
    img = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    pic = source_picture(img, t, 2.0)
    assert pic.shape == (2 * SHAPE[0], 2 * SHAPE[1], 3) and pic.dtype == np.uint8
    for _, r in t.iterrows():
        pts = np.asarray(list(r["centerline"]), float)
        x, y = np.round(pts[len(pts) // 2] * 2.0).astype(int)
        if y < 12 + 20 * 4:  # under the legend
            continue
        assert tuple(pic[y, x]) == SOURCE_COLOURS[r["source"]]
    # 16-bit and colour frames draw alike; a scale must be positive.
    assert source_picture(quantise(photo(), np.uint16), t).shape == (*SHAPE, 3)
    with pytest.raises(ValueError):
        source_picture(img, t, 0.0)


def test_the_parameters_decide_the_quality_too(tmp_path: Path) -> None:
    # The quality flag reads the source section (here: any light beyond an end doubts it),
    # as in a session's frames, not the defaults.
    paths = write_photos(tmp_path)[:1]
    ok = int(detect_photos(paths).table["quality_ok"].sum())
    strict = DetectParams.from_dict({"source": {"end_light_max": 1e-6}})
    got = detect_photos(paths, strict).table
    assert ok > 0 and int(got["quality_ok"].sum()) < ok
    assert int((got["reason"] == "ok").sum()) == int(got["quality_ok"].sum())


def _lights(faint_only: bool = False) -> np.ndarray:
    """Twelve bright lights drawing their whole 38 px path, wide (bloomed: not point-like),
    and eight faint ones of which only the first 13 px show (a fragment of the same kind of
    path); 8-bit."""
    shape = (260, 400)
    bright = line_grid(12, 6, (20.0, 20.0), (60.0, 70.0), (12.0, 36.0))
    faint = line_grid(8, 4, (30.0, 170.0), (90.0, 45.0), (4.0, 12.0))
    img = render_streaks(shape, faint, 0.8, 1.2, 0.03, 0.004, 1)
    if not faint_only:
        img = img + render_streaks(shape, bright, 6.0, 2.2, 0.0, 0.0, 2)
    return quantise(img, np.uint8)


def test_faint_lights_showing_part_of_the_path_are_fragments_where_whole_lights_say_so(
    tmp_path: Path,
) -> None:
    # Derived truth: the faint lights' streaks are a third of the whole lights' path. Their
    # first-pass verdict is quality_ok (they are the frame's only clean point lights and
    # agree with each other); the photograph's whole lights make them fragments.
    img = _lights()
    fs = detect_frame(img)
    fs.quality, fs.one_doubt = frame_quality(fs, DetectParams())
    before = np.asarray(fs.quality[2], bool)
    chord = np.hypot(*(fs.end_b - fs.end_a).T)
    assert before.sum() == 8 and np.all(np.abs(chord[before] - np.hypot(4.0, 12.0)) < 1.0)
    path = tmp_path / "lights.png"
    cv2.imwrite(str(path), img)
    t = detect_photos([path]).table
    assert not t["quality_ok"].any()
    assert int((t["reason"] == "fragment").sum()) >= 8
    # Negative control: the faint lights alone say nothing against themselves.
    alone = tmp_path / "faint.png"
    cv2.imwrite(str(alone), _lights(faint_only=True))
    assert int(detect_photos([alone]).table["quality_ok"].sum()) == 8
