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
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from blurtrack.errors import ImportFormatError
from blurtrack.features.pairs import usable_cores
from blurtrack.geometry.camera import Camera
from blurtrack.io.importers.common import (
    MAX_FRAMES,
    check_readout,
    exposure_ns,
    frame_start_ns,
    guessed_intrinsics,
    rate_hz,
    read_image,
    text_lines,
)
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, encode_frame

T = TypeVar("T")
R = TypeVar("R")

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: Nanoseconds per time unit.
TIME_UNITS = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}
#: Frame interval range (s) the detected unit must put the median frame interval in.
FRAME_INTERVAL_S = (2e-3, 2.0)
#: Gyro sample interval range (s) the detected unit must put the median gyro interval in.
GYRO_INTERVAL_S = (1e-4, 0.1)
GYRO_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
#: |ω| above this (35 rad/s = 2000 deg/s, the largest common MEMS full scale) cannot be rad/s.
MAX_RADPS = 35.0
_SPLIT = re.compile(r"[,;\t ]+")
_NUMBER = re.compile(r"(\d+)")
_TIME_NAMES = ("t", "time", "timestamp", "ts", "stamp", "t_s", "t_ns", "time_s", "timestamp_ns")
_AXIS_NAMES = {
    "wx": ("wx", "gx", "w_x", "gyro_x", "gyrox", "omega_x", "x"),
    "wy": ("wy", "gy", "w_y", "gyro_y", "gyroy", "omega_y", "y"),
    "wz": ("wz", "gz", "w_z", "gyro_z", "gyroz", "omega_z", "z"),
}


def _decimal(text: str, where: str) -> Decimal:
    try:
        d = Decimal(text.strip())
    except InvalidOperation:
        raise ImportFormatError(f"{where}: {text.strip()!r} is not a number") from None
    if not d.is_finite():
        raise ImportFormatError(f"{where}: {text.strip()!r} is not finite")
    return d


def _is_number(text: str) -> bool:
    try:
        return Decimal(text.strip()).is_finite()
    except InvalidOperation:
        return False


def _numeric_table(path: Path, min_fields: int) -> bool:
    """Whether the first data line of ``path`` (after comments and one header line) is
    ``min_fields`` or more numbers: a table, not a free-form log."""
    try:
        with path.open(encoding="utf-8", errors="replace") as f:
            seen = 0
            for line in f:
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                tokens = [t for t in _SPLIT.split(s) if t]
                if all(_is_number(t) for t in tokens):
                    return len(tokens) >= min_fields
                seen += 1
                if seen > 1:
                    return False
    except OSError:
        return False
    return False


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
        found = [p for p in found if _numeric_table(p, min_fields)]
    if len(found) != 1:
        names = ", ".join(p.name for p in found) or "none"
        raise ImportFormatError(f"frames: {what} file not found unambiguously ({names}); {flag}")
    return found[0]


def _confined(src: Path, given: str | Path | None) -> Path | None:
    """``given`` as a path: relative names are taken inside ``src``."""
    if given is None:
        return None
    p = Path(given)
    return p if p.is_absolute() else src / p


def image_folder(src: Path, images: str | Path | None) -> tuple[Path, list[Path]]:
    """The folder of frames and its image files in name order."""
    folder = _confined(src, images)
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


def _rows(path: Path) -> tuple[list[str] | None, list[list[str]], int]:
    """(header tokens or None, rows of tokens, line number of the first row) of a text table;
    ``#`` comment lines and blank lines are skipped."""
    header: list[str] | None = None
    rows: list[list[str]] = []
    first = 0
    for n, line in enumerate(text_lines(path), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tokens = [t for t in _SPLIT.split(s) if t]
        if not rows and header is None and not any(_is_number(t) for t in tokens):
            header = [t.strip().lower() for t in tokens]
            continue
        if not rows:
            first = n
        rows.append(tokens)
    return header, rows, first


def frame_times(path: Path, files: list[Path]) -> tuple[list[tuple[Path, Decimal]], str]:
    """Each image with its raw time from ``path`` (in the file's unit), and how frames were
    matched to lines."""
    _, rows, first = _rows(path)
    if not rows:
        raise ImportFormatError(f"{path}: no frame times")
    by_name = {p.name: p for p in files}
    if all(len(r) == 2 for r in rows) and any(not _is_number(t) for t in rows[0]):
        out = []
        for n, r in enumerate(rows, start=first):
            name, t = (r[1], r[0]) if _is_number(r[0]) else (r[0], r[1])
            if name not in by_name:
                raise ImportFormatError(f"{path} line {n}: no image {name!r} in the image folder")
            out.append((by_name[name], _decimal(t, f"{path} line {n}")))
        if len({p for p, _ in out}) != len(out):
            raise ImportFormatError(f"{path}: an image is named on two lines")
        out.sort(key=lambda pt: pt[1])
        return out, "by the file names in the frame-times file"
    if any(len(r) != 1 for r in rows):
        raise ImportFormatError(
            f"{path}: expected one time per line or 'time,filename' rows, "
            f"got {len(rows[0])} fields on line {first}"
        )
    times = [_decimal(r[0], f"{path} line {first + i}") for i, r in enumerate(rows)]
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


def _unit(values: list[Decimal], given: str | None, span: tuple[float, float], what: str) -> str:
    """The time unit of ``values`` (raw): the one that puts their median positive step in
    ``span`` seconds; ``given`` (``--time-unit``) must do so too (a wrong unit makes 30 fps
    30 000 fps or one frame in 33 s: refused, not imported)."""
    if given is not None and given not in TIME_UNITS:
        raise ImportFormatError(f"time unit must be one of {list(TIME_UNITS)}, got {given!r}")
    arr = np.array([float(v) for v in values])
    d = np.abs(np.diff(arr))
    d = d[d > 0]
    if d.size == 0:
        raise ImportFormatError(f"{what}: fewer than 2 distinct times")
    step = float(np.median(d))
    fits = [u for u, ns in TIME_UNITS.items() if span[0] <= step * ns * 1e-9 < span[1]]
    if given is not None:
        if given not in fits:
            raise ImportFormatError(
                f"{what}: with --time-unit {given} the median step is "
                f"{step * TIME_UNITS[given] * 1e-9:g} s, outside [{span[0]:g}, {span[1]:g}) s"
            )
        return given
    if len(fits) != 1:
        raise ImportFormatError(
            f"{what}: a median step of {step:g} fits no time unit with a step in "
            f"[{span[0]:g}, {span[1]:g}) s; give --time-unit"
        )
    return fits[0]


def _to_ns(v: Decimal, unit: str) -> int:
    return int((v * TIME_UNITS[unit]).to_integral_value())


def gyro_columns(
    header: list[str] | None, rows: list[list[str]], given: str | None, path: Path
) -> tuple[dict[str, int], str]:
    """Column index of ``t``, ``wx``, ``wy``, ``wz`` and how they were found."""
    width = len(rows[0])
    if given is not None:
        names = [c.strip().lower() for c in given.split(",")]
        if sorted(n for n in names if n != "-") != ["t", "wx", "wy", "wz"] or len(names) > width:
            raise ImportFormatError(
                f"--gyro-columns must name t, wx, wy, wz once each ('-' skips a column) "
                f"within the file's {width} columns, got {given!r}"
            )
        return {n: i for i, n in enumerate(names) if n != "-"}, "--gyro-columns"
    if header is not None and len(header) == width:
        cols: dict[str, int] = {}
        for i, h in enumerate(header):
            key = h.split("[")[0].strip().strip("#").strip()
            if "t" not in cols and (key in _TIME_NAMES or "time" in key or "stamp" in key):
                cols["t"] = i
            for axis, aliases in _AXIS_NAMES.items():
                if axis not in cols and key in aliases:
                    cols[axis] = i
        if len(cols) == 4:
            return cols, f"the header ({', '.join(header)})"
    if width not in (4, 7):
        raise ImportFormatError(
            f"{path}: {width} columns and no header naming them; give --gyro-columns"
        )
    data = np.array([[float(t) for t in r] for r in rows[: min(len(rows), 2000)]])
    rising = [
        i for i in range(width) if np.all(np.diff(data[:, i]) >= 0) and np.ptp(data[:, i]) > 0
    ]
    if len(rising) != 1:
        raise ImportFormatError(
            f"{path}: cannot tell the time column ({len(rising)} columns increase); "
            "give --gyro-columns"
        )
    t = rising[0]
    rest = [i for i in range(width) if i != t][:3]
    if t not in (0, width - 1):
        raise ImportFormatError(
            f"{path}: the increasing column {t + 1} is neither first nor last; give --gyro-columns"
        )
    return dict(zip(("t", "wx", "wy", "wz"), [t, *rest], strict=True)), (
        f"time = the increasing column {t + 1}, gyro x, y, z = columns "
        f"{', '.join(str(i + 1) for i in rest)}"
    )


def read_gyro(
    path: Path, columns: str | None, time_unit: str | None, gyro_unit: str | None
) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    """``(t_ns (N,), omega_radps (N, 3), assumptions)`` of a gyro CSV, sorted, repeats dropped."""
    header, rows, first = _rows(path)
    if len(rows) < 2:
        raise ImportFormatError(f"{path}: fewer than 2 gyro rows")
    width = len(rows[0])
    for n, r in enumerate(rows, start=first):
        if len(r) != width:
            raise ImportFormatError(f"{path}: row {n - first + 1} has {len(r)} fields, not {width}")
    cols, how = gyro_columns(header, rows, columns, path)
    raw_t = [_decimal(r[cols["t"]], f"{path} row {i + 1}") for i, r in enumerate(rows)]
    try:
        w = np.array([[float(r[cols[a]]) for a in ("wx", "wy", "wz")] for r in rows])
    except ValueError:
        raise ImportFormatError(f"{path}: a gyro value is not a number") from None
    if not np.all(np.isfinite(w)):
        raise ImportFormatError(f"{path}: non-finite gyro value")
    unit = _unit(raw_t, time_unit, GYRO_INTERVAL_S, str(path))
    t_ns = np.array([_to_ns(v, unit) for v in raw_t], np.int64)
    peak = float(np.abs(w).max())
    if gyro_unit is None:
        g_unit = "deg/s" if peak > MAX_RADPS else "rad/s"
        g_how = (
            f"deg/s (peak {peak:.1f} exceeds {MAX_RADPS} rad/s)"
            if g_unit == "deg/s"
            else f"rad/s (peak {peak:.3g}; give --gyro-unit deg/s if it is not)"
        )
    elif gyro_unit in GYRO_UNITS:
        g_unit, g_how = gyro_unit, f"{gyro_unit} (from --gyro-unit)"
    else:
        raise ImportFormatError(f"--gyro-unit must be one of {list(GYRO_UNITS)}, got {gyro_unit!r}")
    omega = w * GYRO_UNITS[g_unit]
    if float(np.abs(omega).max()) > MAX_RADPS:
        raise ImportFormatError(
            f"{path}: gyro peak {float(np.abs(omega).max()):.1f} rad/s exceeds {MAX_RADPS} rad/s"
        )
    order = np.argsort(t_ns, kind="stable")
    keep = order[np.r_[True, np.diff(t_ns[order]) > 0]]
    assumptions = {
        "gyro_columns": how,
        "gyro_time_unit": f"{unit}" + (" (from --time-unit)" if time_unit else " (detected)"),
        "gyro_unit": g_how,
    }
    return t_ns[keep], omega[keep], assumptions


def in_order(fn: Callable[[T], R], items: Sequence[T], workers: int) -> Iterator[R]:
    """``fn(item)`` of each item, in order, computed on up to ``workers`` threads with at most
    ``2 · workers`` results waiting (decoding and PNG encoding release the GIL: an import's
    frames are encoded two at a time on two cores, and memory stays bounded)."""
    if workers <= 1:
        yield from (fn(i) for i in items)
        return
    with ThreadPoolExecutor(workers) as pool:
        window: deque[Future[R]] = deque()
        for item in items:
            window.append(pool.submit(fn, item))
            if len(window) >= 2 * workers:
                yield window.popleft().result()
        while window:
            yield window.popleft().result()


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
    times_path = _confined(src, frame_times_file) or _find_one(
        src, ("*frame*", "*stamp*", "*times*"), "frame-times", "give --frame-times", 1
    )
    gyro_path = _confined(src, gyro) or _find_one(
        src, ("*gyro*", "*imu*"), "gyro", "give --gyro", 4
    )
    pairs, matched = frame_times(times_path, files)
    if max_frames is not None:
        pairs = pairs[: int(max_frames)]
    f_unit = _unit([t for _, t in pairs], time_unit, FRAME_INTERVAL_S, str(times_path))
    exp = exposure_ns(exposure_s, "frames")
    readout = check_readout(0.0 if readout_s is None else readout_s, "frames")
    stamp = stamp or "start"
    starts = [frame_start_ns(_to_ns(t, f_unit), stamp, exp, readout) for _, t in pairs]
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
