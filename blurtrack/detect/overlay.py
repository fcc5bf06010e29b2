"""Pictures of detected streaks drawn over their frame (for the demo and for inspection)."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

#: BGR colours: centre line, start, end, flagged streaks' centre line.
LINE = (60, 220, 60)
START = (40, 40, 255)
END = (255, 160, 40)
FLAGGED = (0, 200, 255)


def draw_streaks(image: np.ndarray, rows: pd.DataFrame, scale: int = 2) -> np.ndarray:
    """Draw the streaks of ``rows`` (streak-table rows of one frame) over ``image``.

    The frame is converted to 8-bit BGR and upscaled by ``scale`` so that sub-pixel lines stay
    visible. Centre lines in green (orange when flagged), start of exposure as a red dot, end
    as a blue one. Returns the picture ``(H * scale, W * scale, 3)`` uint8.
    """
    img = image
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = (img.astype(np.float32) * 0.7).astype(np.uint8)  # dim, so the drawing stands out
    shift = 4  # fixed-point bits: sub-pixel drawing
    f = float(scale * (1 << shift))

    def fix(xy: ArrayLike) -> np.ndarray:
        # pixel centres are at integer coordinates; the upscaled pixel i spans [i s, (i+1) s)
        return np.rint((np.asarray(xy, float) + 0.5) * f - 0.5 * (1 << shift)).astype(np.int32)

    flag_cols = [c for c in ("clipped", "saturated", "merged", "faint") if c in rows]
    for _, r in rows.iterrows():
        pts = np.asarray(r["centerline"], dtype=float).reshape(-1, 2)
        flagged = bool(any(r[c] for c in flag_cols))
        if len(pts) >= 2:
            cv2.polylines(
                img,
                [fix(pts).reshape(-1, 1, 2)],
                False,
                FLAGGED if flagged else LINE,
                1,
                cv2.LINE_AA,
                shift,
            )
        cv2.circle(
            img, tuple(fix([r["start_x"], r["start_y"]])), 3 << shift, START, -1, cv2.LINE_AA, shift
        )
        cv2.circle(
            img, tuple(fix([r["end_x"], r["end_y"]])), 3 << shift, END, -1, cv2.LINE_AA, shift
        )
    return img
