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
