"""The demo's detection step (``make demo``): streak table, a picture, a summary.

``blurtrack.demo`` (the lead's demo driver) calls :func:`detection_demo` on the simulated
session it has just written; it is also usable on its own::

    from blurtrack.detect.demo import detection_demo
    summary = detection_demo("demo_out/session", "demo_out/detect")
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2

from blurtrack.detect.overlay import draw_streaks
from blurtrack.detect.session import detect_session
from blurtrack.detect.table import write_table
from blurtrack.errors import DetectionError
from blurtrack.io.session import load_session


def detection_demo(
    session_folder: str | Path, out_dir: str | Path, crop: tuple[int, int, int, int] | None = None
) -> dict[str, Any]:
    """Detect the streaks of a session and illustrate them.

    Writes ``out_dir/streaks.parquet``, ``out_dir/streaks_overlay.png`` (detected streaks over
    the first frame with streaks; ``crop = (x, y, w, h)`` limits it to a region, upscaled 4x,
    so that sub-pixel ends are visible) and ``out_dir/summary.json``; returns the summary.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    session = load_session(session_folder)
    result = detect_session(session)
    table_path = out / "streaks.parquet"
    write_table(result.table, table_path)
    first = int(result.table["frame"].iloc[0])
    rows = result.table[result.table["frame"] == first]
    image = session.read_image(first)
    scale = 2
    if crop is not None:
        x, y, w, h = crop
        image = image[y : y + h, x : x + w]
        rows = rows.copy()
        for c in ("start_x", "end_x"):
            rows[c] = rows[c] - x
        for c in ("start_y", "end_y"):
            rows[c] = rows[c] - y
        rows["centerline"] = [[[p[0] - x, p[1] - y] for p in cl] for cl in rows["centerline"]]
        scale = 4
    picture = out / "streaks_overlay.png"
    if not cv2.imwrite(str(picture), draw_streaks(image, rows, scale)):
        raise DetectionError(f"cannot write {picture}")
    summary = dict(result.summary, table=str(table_path), overlay=str(picture), overlay_frame=first)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
