"""The demo's pictures explain themselves (issue 46): ``detect --overlay`` draws a titled,
legended picture about 1600 px wide with a zoomed inset; ``before_after.png`` has labelled
panels with the PSNR/SSIM numbers on the picture."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from blurtrack.detect.overlay import (
    densest_window,
    flagged_mask,
    streak_figure,
    write_streak_picture,
)


def _frame_and_rows(w: int = 1280, h: int = 720) -> tuple[np.ndarray, pd.DataFrame]:
    img = np.full((h, w), 8, np.uint8)
    rows = []
    for k, (x, y) in enumerate((x, y) for y in range(60, h, 120) for x in range(60, w, 160)):
        cv2.line(img, (x, y), (x + 20, y + 6), 200, 2)
        rows.append(
            {
                "start_x": float(x), "start_y": float(y),
                "end_x": float(x + 20), "end_y": float(y + 6),
                "centerline": np.array([[x, y], [x + 10, y + 3], [x + 20, y + 6]], float),
                "quality_ok": k % 7 != 0,
            }
        )  # fmt: skip
    return img, pd.DataFrame(rows)


def test_streak_figure_has_title_legend_and_inset() -> None:
    img, rows = _frame_and_rows()
    n, bad = len(rows), int((~rows["quality_ok"]).sum())
    fig = streak_figure(img, rows, frame=3)
    title = fig.get_suptitle()
    assert f"frame 3: {n} streaks" in title and f"{n - bad} quality_ok" in title
    (main,) = fig.axes
    (inset,) = main.child_axes  # the zoomed inset
    labels = [t.get_text() for t in main.get_legend().get_texts()]
    assert labels[0] == f"centre line, quality_ok ({n - bad})"
    assert labels[1] == f"centre line, flagged ({bad})"
    x0, x1 = inset.get_xlim()
    assert 100 < x1 - x0 < 0.5 * img.shape[1]  # a region at 2 picture px per frame px
    assert "zoom" in inset.texts[0].get_text()


def test_overlay_picture_is_about_1600_px_wide(tmp_path: Path) -> None:
    img, rows = _frame_and_rows(2560, 1440)  # a frame larger than the picture: scaled down
    out = write_streak_picture(tmp_path / "detect.png", img, rows, 0)
    pic = cv2.imread(str(out))
    assert pic.shape[1] == 1600 and 0.5 < pic.shape[0] / pic.shape[1] < 0.65


def test_flagged_mask_uses_quality_ok_or_the_flags() -> None:
    assert list(flagged_mask(pd.DataFrame({"quality_ok": [True, False]}))) == [False, True]
    legacy = pd.DataFrame({"clipped": [False, True], "saturated": [False, False]})
    assert list(flagged_mask(legacy)) == [False, True]


def test_densest_window_finds_the_cluster() -> None:
    mid = np.array([[10.0, 10.0], [500.0, 300.0], [510.0, 310.0], [520.0, 305.0]])
    x0, y0 = densest_window(mid, (100.0, 80.0), (400, 800))
    assert x0 <= 500 and x0 + 100 > 520 and y0 <= 300 and y0 + 80 > 310
    x0, _ = densest_window(mid, (100.0, 80.0), (400, 800), np.array([10.0, 1, 1, 1]))
    assert x0 <= 10  # a heavier (flagged) streak draws the window


def test_before_after_panels_are_labelled_and_carry_the_numbers() -> None:
    from blurtrack.cli.demo import before_after_figure
    from blurtrack.detect.overlay import figure_pixels

    rng = np.random.default_rng(0)
    sharp = rng.uniform(0, 1, (36, 48, 3)).astype(np.float32)
    fig = before_after_figure(sharp * 0.9, sharp * 0.95, sharp, (23.19, 0.69), (28.44, 0.843), "x")
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == ["(a) blurred input", "(b) GAMD output", "(c) sharp reference"]
    notes = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert "PSNR 23.19 dB" in notes[0] and "SSIM 0.690" in notes[0]
    assert "PSNR 28.44 dB (+5.25 dB)" in notes[1] and "SSIM 0.843 (+0.153)" in notes[1]
    assert fig.get_suptitle() == "GAMD deblurring on x"
    pic = figure_pixels(fig)
    # each panel at a whole number of pixels per image pixel, at least 480 px wide
    assert pic.shape[1] >= 3 * 480 and pic.shape[0] > 400
    assert fig.axes[0].get_images()[0].get_interpolation() == "nearest"
