"""``blurtrack detect PHOTO ... --out FILE``: the streak table of still photographs
(:mod:`blurtrack.detect.photos`), its summary beside it, and with ``--overlay`` each
photograph's detections coloured by their source."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from blurtrack.errors import DetectionError
from blurtrack.io.atomic import write_json_atomic
from blurtrack.io.guard import check_output

#: What ``detect`` says of photographs, and of a session detected without its gyro
#: (docs/detection.md, Known limits: on ``hard`` seed 4, 378 of 1168 such ``quality_ok``
#: streaks are wrong).
IMAGE_ONLY_NOTE = (
    "without a gyro: quality_ok comes from the images alone, which cannot see a dot's path turn "
    "back within the exposure (a hairpin or hook); on shake that turns, many such ends are "
    "wrong (docs/detection.md, Known limits)"
)


def _overlay_paths(overlay: Path | None, photos: list[Path]) -> list[Path]:
    """Where each photograph's picture goes: ``overlay`` itself for one photograph, else
    ``overlay/<stem>.png`` (two photographs with one stem are refused); none without
    ``overlay``."""
    if overlay is None:
        return []
    if len(photos) == 1:
        return [overlay]
    stems: dict[str, Path] = {}
    for p in photos:
        if p.stem in stems:
            raise DetectionError(
                f"--overlay: two photographs would share the picture {p.stem}.png "
                f"({os.fsdecode(stems[p.stem])!r}, {os.fsdecode(p)!r})"
            )
        stems[p.stem] = p
    return [overlay / f"{p.stem}.png" for p in photos]


def _check_options(args: argparse.Namespace) -> None:
    """The session options a photograph has nothing for."""
    if args.out is None:
        raise DetectionError("photographs need --out (the streak table's path)")
    if args.gyro == "on":
        raise DetectionError("--gyro on: photographs have no gyro (use auto or off)")
    if args.frames is not None:
        raise DetectionError("--frames selects a session's frames; name the photographs instead")


def run_photos(args: argparse.Namespace, photos: list[Path]) -> int:
    """``detect`` on photographs: check every output first, detect, write the table, the
    summary and the pictures, and print one line per photograph."""
    import cv2

    from blurtrack.detect import DetectParams
    from blurtrack.detect.overlay import write_source_picture
    from blurtrack.detect.photos import detect_photos, value_counts
    from blurtrack.detect.session.pipeline import default_workers
    from blurtrack.detect.session.table import TABLE_VERSION, write_table
    from blurtrack.io.images import read_image

    _check_options(args)
    out: Path = args.out
    summary_path = out.with_name(out.stem + ".summary.json")
    inputs: list[Any] = [*photos, args.params]
    check_output(out, force=args.force, inputs=inputs, siblings=[summary_path.name])
    pictures = _overlay_paths(args.overlay, photos)
    if len(photos) > 1 and pictures:
        check_output(args.overlay, folder=True, force=True, inputs=inputs, what="--overlay")
    for pic in pictures:
        check_output(pic, force=args.force, inputs=inputs, what="--overlay")
    params = DetectParams.from_yaml(args.params) if args.params else DetectParams()
    cv2.setNumThreads(1)  # one core a worker, as a session's frames
    result = detect_photos(
        photos, params, default_workers() if args.workers is None else args.workers
    )
    write_table(result.table, out)
    table = result.table
    summary: dict[str, Any] = {
        "photos": result.photos,
        "streaks": len(table),
        "quality_ok": int(table["quality_ok"].sum()),
        "source": value_counts(table["source"]),
        "reason": value_counts(table["reason"]),
        "gyro": "off",
        "table_version": TABLE_VERSION,
        "params": params.to_dict(),
        "table": os.fsdecode(out),
    }
    for k, (photo, pic) in enumerate(zip(photos, pictures, strict=False)):
        pic.parent.mkdir(parents=True, exist_ok=True)
        image = read_image(photo, what="photograph")
        write_source_picture(pic, image, table[table["frame"] == k])
        result.photos[k]["overlay"] = os.fsdecode(pic)
    write_json_atomic(summary_path, summary)
    print(f"detect: {len(table)} streaks in {len(photos)} photograph(s) -> {os.fsdecode(out)}")
    for ph in result.photos:
        src = ", ".join(f"{n} {k}" for k, n in sorted(ph["source"].items()))
        print(
            f"  {ph['photo']}: {ph['streaks']} streaks ({src or 'none'}), "
            f"{ph['quality_ok']} quality_ok"
        )
    print(f"  note: {IMAGE_ONLY_NOTE}")
    return 0
