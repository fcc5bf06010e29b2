"""The two real light-streak photographs (``../shared/data/real/light-streaks``; skipped without
them): ``quality_ok`` only on whole point lights, each one looked at by eye.

night2's four ``quality_ok`` lights were checked one by one on
``docs/figures/real_night2_source.png`` (whole string lights, hook to foot: above the door, two
right of the bushes, one in the middle right); night1 has no whole light that the frame's
other lights agree with (docs/detection.md, "Real photographs"). Any other
``quality_ok`` streak would lie on a lit facade, a sign, glare, a bush or a chain of lights."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from blurtrack.detect import detect_frame
from blurtrack.detect.session.orientation import combine
from blurtrack.detect.session.table import build_table, frame_rows

#: night2's whole string lights found ``quality_ok`` (time midpoints, px of the photograph).
NIGHT2_WHOLE_LIGHTS = np.array([[665.0, 312.0], [795.0, 438.0], [479.0, 524.0], [399.0, 475.0]])
#: How near (px) a ``quality_ok`` midpoint lies to its light: a quarter of a light's ~40 px.
NEAR_PX = 10.0


def _ok_midpoints(shared_data: Path, name: str) -> np.ndarray:
    img = cv2.imread(str(shared_data / "real" / "light-streaks" / name), cv2.IMREAD_UNCHANGED)
    assert img is not None
    fs = detect_frame(img)
    table = build_table([frame_rows(0, 0, fs, combine(np.zeros((len(fs), 3))))])
    assert len(table) > 50  # the photograph's lights are detected, not refused wholesale
    return table.loc[table.quality_ok, ["mid_x", "mid_y"]].to_numpy(float)


def test_night2_quality_ok_only_on_its_whole_lights(shared_data: Path) -> None:
    mids = _ok_midpoints(shared_data, "night2.jpg")
    d = np.linalg.norm(mids[:, None] - NIGHT2_WHOLE_LIGHTS[None], axis=2)
    assert np.all(d.min(axis=1) <= NEAR_PX), mids  # none elsewhere
    assert int(np.sum(d.min(axis=0) <= NEAR_PX)) >= 3  # and most of them found


def test_night1_has_no_quality_ok_streak(shared_data: Path) -> None:
    assert len(_ok_midpoints(shared_data, "night1.jpg")) == 0
