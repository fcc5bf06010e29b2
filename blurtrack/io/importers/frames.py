"""The commonest lab layout: a folder of frames, a file of frame times, a gyro CSV.

``SRC`` holds (names found by pattern unless given):

- images (``.png .jpg .jpeg .tif .tiff .bmp``) in ``SRC`` itself or in its one sub-folder that
  holds images (``--images``);
- a frame-times file (``--frame-times``; found as the one ``*frame*`` / ``*stamp*`` / ``*times*``
  text file): either one time per line (line ``k`` is frame ``k``, 1-based; a frame's ``k`` is
  the last number in its file name, or its rank in name order when the names carry no numbers
  or the file has exactly one line per image) or ``time,filename`` / ``filename,time`` rows;
- a gyro CSV (``--gyro``; found as the one ``*gyro*`` / ``*imu*`` text file): comma, semicolon,
  tab or space separated rows, an optional header, with a time column and three gyro columns
  (``--gyro-columns``, e.g. ``wx,wy,wz,t`` or ``t,wx,wy,wz``; ``-`` skips a column).

What the files do not say is detected where the data decide it, and stated otherwise (in the
returned summary's ``assumptions`` and ``session.yaml``'s ``import.assumptions``):

- time unit (``--time-unit s|ms|us|ns``, frames and gyro on one clock): the unit that puts the
  median frame interval in [2 ms, 2 s) (500 to 0.5 frames per second) and the median gyro
  interval in [0.1 ms, 0.1 s) (10 Hz to 10 kHz); the two files may differ;
- time column (when no header names it): the one column that increases row over row;
- gyro unit (``--gyro-unit rad/s|deg/s``): deg/s when some sample exceeds 35 rad/s (2000 deg/s,
  the largest full scale of common MEMS gyros), rad/s otherwise (an assumption: printed);
- frame stamp: start of exposure unless ``--stamp middle``; the time offset is calibrated.

Axes are never known from this layout (``axes_known: false``); intrinsics are a stated guess
unless ``--intrinsics`` gives them.
"""

from __future__ import annotations

import itertools
import re
from decimal import Decimal
from pathlib import Path
from typing import Any

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.features.pairs import in_order, usable_cores
from blurtrack.geometry.camera import Camera
from blurtrack.io.importers.common import (
    MAX_FRAMES,
    check_readout,
    exposure_ns,
    frame_start_ns,
    guessed_intrinsics,
    rate_hz,
    read_image,
)
from blurtrack.io.importers.tables import (
    FRAME_INTERVAL_S,
    decimal_of,
    is_number,
    numeric_table,
    read_gyro,
    table_rows,
    to_ns,
    unit_of,
)
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, encode_frame

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
_NUMBER = re.compile(r"(\d+)")


def _find_one(src: Path, patterns: tuple[str, ...], what: str, flag: str, min_fields: int) -> Path:
    """The one text file of ``src`` matching ``patterns`` whose rows are number tables."""
    found = sorted(
        {
            p
            for pat in patterns
            for p in src.glob(pat)
            if p.is_file() and p.suffix.lower() in (".txt", ".csv", ".tsv", "")
        }
    )
    if len(found) > 1:
        found = [p for p in found if numeric_table(p, min_fields)]
    if len(found) != 1:
        names = ", ".join(p.name for p in found) or "none"
        raise ImportFormatError(f"frames: {what} file not found unambiguously ({names}); {flag}")
    return found[0]


def _option_path(src: Path, given: str | Path | None) -> Path | None:
    """``given`` as a path: relative names are taken inside ``src``."""
    if given is None:
        return None
    p = Path(given)
    return p if p.is_absolute() else src / p


def image_folder(src: Path, images: str | Path | None) -> tuple[Path, list[Path]]:
    """The folder of frames and its image files in name order."""
    folder = _option_path(src, images)
    subfolders = sorted(p for p in src.iterdir() if p.is_dir())
    candidates = [folder] if folder is not None else [src, *subfolders]
    with_images = []
    for c in candidates:
        if not c.is_dir():
            raise ImportFormatError(f"frames: image folder {c} not found")
        files = sorted(p for p in c.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if files:
            with_images.append((c, files))
    if len(with_images) != 1:
        names = ", ".join(str(c) for c, _ in with_images) or "none"
        raise ImportFormatError(
            f"frames: expected one folder of images in {src}, found {names}; give --images"
        )
    folder, files = with_images[0]
    if len(files) > MAX_FRAMES:
        raise ImportFormatError(f"frames: {len(files)} images, more than {MAX_FRAMES}")
    return folder, files


def _frame_number(path: Path) -> int | None:
    nums = _NUMBER.findall(path.stem)
    return int(nums[-1]) if nums else None


def frame_times(path: Path, files: list[Path]) -> tuple[list[tuple[Path, Decimal]], str]:
    """Each image with its raw time from ``path`` (in the file's unit), and how frames were
    matched to lines."""
    _, rows, first = table_rows(path)
    if not rows:
        raise ImportFormatError(f"{path}: no frame times")
    by_name = {p.name: p for p in files}
    if all(len(r) == 2 for r in rows) and any(not is_number(t) for t in rows[0]):
        out = []
        for n, r in enumerate(rows, start=first):
            name, t = (r[1], r[0]) if is_number(r[0]) else (r[0], r[1])
            if name not in by_name:
                raise ImportFormatError(f"{path} line {n}: no image {name!r} in the image folder")
            out.append((by_name[name], decimal_of(t, f"{path} line {n}")))
        if len({p for p, _ in out}) != len(out):
            raise ImportFormatError(f"{path}: an image is named on two lines")
        out.sort(key=lambda pt: pt[1])
        return out, "by the file names in the frame-times file"
    if any(len(r) != 1 for r in rows):
        raise ImportFormatError(
            f"{path}: expected one time per line or 'time,filename' rows, "
            f"got {len(rows[0])} fields on line {first}"
        )
    times = [decimal_of(r[0], f"{path} line {first + i}") for i, r in enumerate(rows)]
    numbers = [_frame_number(p) for p in files]
    if len(times) == len(files) or any(k is None for k in numbers):
        if len(times) != len(files):
            raise ImportFormatError(
                f"{path}: {len(times)} times for {len(files)} images whose names carry no number"
            )
        return list(zip(files, times, strict=True)), "line k = k-th image in name order"
    ks = [int(k) for k in numbers if k is not None]
    if len(set(ks)) != len(ks):
        raise ImportFormatError(f"{path}: two images carry the same frame number")
    bad = [p.name for p, k in zip(files, ks, strict=True) if not 1 <= k <= len(times)]
    if bad:
        raise ImportFormatError(
            f"{path}: {len(times)} lines, but image {bad[0]} has a frame number outside "
            f"1..{len(times)}"
        )
    pairs = sorted(zip(ks, files, strict=True))
    return [(p, times[k - 1]) for k, p in pairs], "line k = the image whose name ends in k"


def import_frames(
    src: str | Path,
    out: str | Path,
    *,
    images: str | Path | None = None,
    frame_times_file: str | Path | None = None,
    gyro: str | Path | None = None,
    gyro_columns: str | None = None,
    time_unit: str | None = None,
    gyro_unit: str | None = None,
    exposure_s: float | None = None,
    readout_s: float | None = None,
    stamp: str | None = None,
    intrinsics: tuple[float, float, float, float] | None = None,
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Import a folder of frames, a frame-times file and a gyro CSV from ``src`` into a
    session at ``out``; returns the summary (``frames``, ``gyro_samples``, ``assumptions``)."""
    src = Path(src)
    if not src.is_dir():
        raise ImportFormatError(f"frames: {src} is not a folder")
    folder, files = image_folder(src, images)
    times_path = _option_path(src, frame_times_file) or _find_one(
        src, ("*frame*", "*stamp*", "*times*"), "frame-times", "give --frame-times", 1
    )
    gyro_path = _option_path(src, gyro) or _find_one(
        src, ("*gyro*", "*imu*"), "gyro", "give --gyro", 4
    )
    pairs, matched = frame_times(times_path, files)
    if max_frames is not None:
        pairs = pairs[: int(max_frames)]
    f_unit = unit_of([t for _, t in pairs], time_unit, FRAME_INTERVAL_S, str(times_path))
    exp = exposure_ns(exposure_s, "frames")
    readout = check_readout(0.0 if readout_s is None else readout_s, "frames")
    stamp = stamp or "start"
    starts = [frame_start_ns(to_ns(t, f_unit), stamp, exp, readout) for _, t in pairs]
    if any(b <= a for a, b in itertools.pairwise(starts)):
        raise ImportFormatError(f"{times_path}: frame times do not increase with the frame order")
    t_imu, omega, g_assume = read_gyro(gyro_path, gyro_columns, time_unit, gyro_unit)
    lo, hi = int(t_imu[0]), int(t_imu[-1])
    covered = sum(1 for s in starts if lo <= s and s + exp + round(readout * 1e9) <= hi)
    if covered == 0:
        raise ImportFormatError(
            f"frames: the gyro log ({lo * 1e-9:.3f}..{hi * 1e-9:.3f} s) covers none of the frames "
            f"({starts[0] * 1e-9:.3f}..{starts[-1] * 1e-9:.3f} s): another recording, another "
            "clock or another time unit?"
        )
    first = read_image(pairs[0][0])
    h, w = first.shape[:2]
    if intrinsics is not None:
        K = tuple(float(v) for v in intrinsics)
        if len(K) != 4 or not all(np.isfinite(K)) or K[0] <= 0 or K[1] <= 0:
            raise ImportFormatError(f"--intrinsics must be fx,fy,cx,cy with fx, fy > 0, got {K}")
        k_how = "from --intrinsics"
    else:
        K, k_how = guessed_intrinsics(w, h), "GUESS: fx = fy = width, centred principal point"
    assumptions = {
        "frame_times": (
            f"{times_path.name}, unit {f_unit}"
            + (" (from --time-unit)" if time_unit else " (detected)")
            + f", {matched}"
        ),
        **g_assume,
        "exposure_s": f"{exp * 1e-9} (from --exposure-ms)",
        "readout_s": f"{readout} ({'from --readout-ms' if readout_s is not None else 'assumed'};"
        " calibrate fits it)",
        "timestamps": f"frame times taken as the {stamp} of exposure",
        "timeshift_cam_imu_s": "0.0 (one clock assumed; calibrate fits the offset)",
        "camera": f"{K} ({k_how})",
        "R_cam_imu": "UNKNOWN (axes_known: false): identity as a placeholder; calibrate decides",
    }
    meta = SessionMeta(
        camera=Camera((w, h), K, readout_s=readout),
        imu=ImuConfig(rate_hz=rate_hz(t_imu, str(gyro_path)), axes_known=False),
        target_kind="natural",
        extra={"import": {"source": "frames", "path": str(src), "assumptions": assumptions}},
    )

    def encoded(path: Path) -> bytes:
        img = first if path == pairs[0][0] else read_image(path)
        if img.shape[:2] != (h, w):
            raise ImportFormatError(
                f"{path} is {img.shape[1]}x{img.shape[0]}, the first frame {w}x{h}"
            )
        return encode_frame(img, str(path))

    with SessionWriter(out, meta) as wr:
        pngs = in_order(encoded, [p for p, _ in pairs], usable_cores())
        for png, t0 in zip(pngs, starts, strict=True):
            wr.add_png(t0, png, exp)
        wr.add_imu(t_imu, omega)
    return {
        "frames": len(pairs),
        "frames_covered_by_gyro": covered,
        "gyro_samples": int(t_imu.size),
        "resolution": [w, h],
        "image_folder": str(folder),
        "assumptions": assumptions,
    }
