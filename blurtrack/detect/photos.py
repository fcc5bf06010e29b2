"""Detection on still photographs (``blurtrack detect PHOTO ...``): each photograph is one
frame detected from its image alone (:func:`~blurtrack.detect.frame.detect_frame`), with no
gyro, no neighbouring frames and no time.

What a photograph cannot give: which end of a streak is its start (no gyro, no continuity
over frames: every row's ``orientation_source`` is ``none`` at confidence 0.5; start and end
are the measured ends in the order measured), and the gyro's check of the ends. What it
gives is the image's own verdict, as in a session's first pass: each detection's ``source``
(a point light, an extended source, or undetermined) and ``quality_ok`` with its ``reason``.
That is how a lab checks, on its own night photographs, that no lit window, sign or glare is
taken for a point light (docs/detection.md, "Real photographs").

One check more than a session's first pass (:func:`whole_lights_check`), because nothing
else here would make it: the gyro's check in a session refuses a streak whose start-to-end
vector falls short of the dot's predicted one. In a photograph the frame's consensus comes
from its clean point lights alone, and where those are faint lights of which only the slow
part of the path shows (the hook of a "2"), they agree with each other as whole streaks do
(``night2`` at twice its size: 7 hooks of faint lights ``quality_ok``). The frame's whole
lights, the modal cluster of its components measured along their skeletons
(:func:`blurtrack.detect.separation.modal.component_references`), say how long a light's
path is; a ``quality_ok`` streak whose chord falls short of theirs by more than the shape
tolerance is a ``fragment``.

The table is the session table (:mod:`blurtrack.detect.session.table`), one ``frame`` per
photograph in the order given, ``timestamp_ns`` 0; the summary names the photographs.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from blurtrack.detect.context import FrameContext, prepare_and_segment
from blurtrack.detect.forkmap import fork_map
from blurtrack.detect.frame import FrameStreaks, detect_prepared
from blurtrack.detect.params import DetectParams
from blurtrack.detect.separation.consensus import shape_tolerance
from blurtrack.detect.separation.modal import component_references
from blurtrack.detect.separation.quality import frame_quality
from blurtrack.detect.session.orientation import CUE_NAMES, combine
from blurtrack.detect.session.table import build_table, frame_columns
from blurtrack.io.images import read_image

#: Suffixes taken for a photograph (what :func:`blurtrack.io.images.read_image` decodes).
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class PhotoDetection:
    """The streak table of the photographs (``frame`` k: the k-th photograph), their
    per-photograph summaries (:func:`photo_summary`, in order) and their images' streaks."""

    table: pd.DataFrame
    photos: list[dict[str, Any]]
    frames: list[FrameStreaks]


def is_photo(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a photograph (a file with a :data:`PHOTO_SUFFIXES` suffix)
    rather than a session folder."""
    p = Path(path)
    return p.suffix.lower() in PHOTO_SUFFIXES and not p.is_dir()


def whole_lights_check(ctx: FrameContext, fs: FrameStreaks) -> tuple[np.ndarray, np.ndarray]:
    """``fs.quality``'s ``quality_ok`` and ``reason`` after the check of the module text
    (``ctx``: the photograph's context, which ``fs`` was detected in): the ``quality_ok``
    streaks whose chord (``|end_b - end_a|``, px) is shorter than the median chord of the
    photograph's whole lights by more than
    :func:`~blurtrack.detect.separation.consensus.shape_tolerance` of it become
    ``fragment``. Unchanged where no streak is ``quality_ok`` or the photograph has no
    modal cluster of whole lights."""
    assert fs.quality is not None
    ok = np.asarray(fs.quality[2], bool).copy()
    reason = np.asarray(fs.quality[4], object).copy()
    if not ok.any():
        return ok, reason
    got = component_references(ctx, fs.sigma_c_px, fs.sigma_c_px)
    if got is None:
        return ok, reason
    m, _ = got
    whole_chord = float(np.median(np.hypot(*(m.end_b - m.end_a).T)))
    tol = float(shape_tolerance(np.array([[whole_chord, 0.0]]), ctx.params.quality)[0])
    chord = np.hypot(*(fs.end_b - fs.end_a).T)
    short = ok & (chord < whole_chord - tol)
    reason[short] = "fragment"
    return ok & ~short, reason


def photo_summary(path: Path, shape: tuple[int, ...], rows: pd.DataFrame) -> dict[str, Any]:
    """One photograph's counts (``shape``: its image's; ``rows``: its rows of the table): its
    name and size, its detections, how many are ``quality_ok``, and the detections by
    ``source`` and by ``reason``."""
    return {
        "photo": os.fsdecode(path),
        "width_px": int(shape[1]),
        "height_px": int(shape[0]),
        "streaks": len(rows),
        "quality_ok": int(rows["quality_ok"].sum()),
        "source": value_counts(rows["source"]),
        "reason": value_counts(rows["reason"]),
    }


def value_counts(column: pd.Series) -> dict[str, int]:
    """How many rows hold each value of ``column`` (a table's ``source`` or ``reason``), as
    plain JSON-ready types."""
    return {str(k): int(v) for k, v in column.value_counts().items()}


def detect_photos(
    paths: Sequence[str | os.PathLike[str]],
    params: DetectParams | None = None,
    workers: int = 1,
) -> PhotoDetection:
    """Detect the streaks of each photograph of ``paths`` (PNG, JPEG or TIFF; 8 or 16 bit,
    gray or colour; each size-checked from its header before decoding), in ``workers``
    forked processes (:func:`blurtrack.detect.forkmap.fork_map`; the same table as one).
    Raises :class:`blurtrack.io.images.ImageError` (one line) for a file that does not
    decode."""
    p = params or DetectParams()

    def one(k: int) -> tuple[FrameStreaks, tuple[int, ...]]:
        image = read_image(paths[k], what="photograph")
        prep, ctx = prepare_and_segment(image, p)
        fs = detect_prepared(prep, ctx)
        fs.quality, fs.one_doubt = frame_quality(fs, p)  # as a session's frame worker does
        fs.set_verdict(*whole_lights_check(ctx, fs))
        return fs, image.shape

    got = list(fork_map(one, range(len(paths)), workers))
    frames = [fs for fs, _ in got]
    table = build_table(
        [
            frame_columns(k, 0, fs, combine(np.zeros((len(fs), len(CUE_NAMES)))))
            for k, fs in enumerate(frames)
        ]
    )
    photos = [
        photo_summary(Path(path), shape, table[table["frame"] == k])
        for k, (path, (_, shape)) in enumerate(zip(paths, got, strict=True))
    ]
    return PhotoDetection(table, photos, frames)
