"""Physical bounds on what a session may hold, stated once (checked on write and on load).

A value outside these bounds is not a measurement but a damaged or mislabelled file (a gyro
column in deg/s or mdps, a 10 s exposure at 30 fps, two frames naming one image): it is refused
with :class:`~blurtrack.errors.BoundsError`, one line that names the value, where it is and the
bound, which the CLI turns into exit status 2. The bounds are deliberately far above anything a
real rig produces, so that every real recording passes:

- gyro: the largest full-scale range of MEMS gyroscopes is 2000 deg/s (35 rad/s; a few parts
  offer 4000 deg/s, 70 rad/s). :data:`MAX_GYRO_RADPS` is 100 rad/s (5730 deg/s, 16 turns/s).
- accelerometer: consumer parts saturate at 16 g (157 m/s^2), high-g parts at 200-400 g.
  :data:`MAX_ACCEL_MPS2` is 10000 m/s^2 (about 1000 g).
- exposure: a sensor cannot expose a frame longer than the frame period, and the period is the
  spacing of consecutive frame stamps (a multiple of it where frames were dropped). Each
  frame's exposure may exceed the interval to the next frame (the last frame: to the previous
  one) by at most :data:`EXPOSURE_TOL_REL` of it plus :data:`EXPOSURE_TOL_S`, to allow stamp
  jitter and exposure changes between frames. The MARS logger clip exposes 240 ms at 240.03 ms
  intervals (ratio 0.9999); the other real recordings are far below 1.
"""

from __future__ import annotations

import numpy as np

from blurtrack.errors import BoundsError

#: Largest |omega| (norm of the three axes) of a gyro sample, rad/s.
MAX_GYRO_RADPS = 100.0
#: Largest |a| (norm of the three axes) of an accelerometer sample, m/s^2.
MAX_ACCEL_MPS2 = 10_000.0
#: A frame's exposure may exceed its frame interval by this fraction of the interval ...
EXPOSURE_TOL_REL = 0.1
#: ... plus this many seconds.
EXPOSURE_TOL_S = 0.002


def check_gyro(omega_radps: np.ndarray, where: str, first_line: int = 2) -> None:
    """Refuse any gyro sample (N, 3) rad/s whose norm exceeds :data:`MAX_GYRO_RADPS`.

    ``where`` names the file or table; ``first_line`` is the line number of row 0 in it.
    """
    _check_norm(
        omega_radps, MAX_GYRO_RADPS, "rad/s", "gyro rate", "MAX_GYRO_RADPS", where, first_line
    )


def check_accel(accel_mps2: np.ndarray, where: str, first_line: int = 2) -> None:
    """Refuse any accelerometer sample (N, 3) m/s^2 whose norm exceeds :data:`MAX_ACCEL_MPS2`."""
    _check_norm(
        accel_mps2, MAX_ACCEL_MPS2, "m/s^2", "acceleration", "MAX_ACCEL_MPS2", where, first_line
    )


def _check_norm(
    v: np.ndarray, bound: float, unit: str, what: str, name: str, where: str, first_line: int
) -> None:
    v = np.asarray(v, dtype=float).reshape(-1, 3)
    if v.size == 0:
        return
    norm = np.hypot(np.hypot(v[:, 0], v[:, 1]), v[:, 2])  # no overflow for 1e308
    bad = ~(norm <= bound)  # NaN counts as out of bounds
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise BoundsError(
            f"{where}: line {k + first_line}: {what} {norm[k]:.6g} {unit} exceeds the physical "
            f"bound {bound:g} {unit} ({name}, blurtrack/io/bounds.py); is the unit right?"
        )


def max_exposure_ns(interval_ns: np.ndarray | int) -> np.ndarray:
    """Largest exposure (ns) allowed for frames ``interval_ns`` (ns) apart."""
    iv = np.asarray(interval_ns, dtype=np.float64)
    return iv * (1.0 + EXPOSURE_TOL_REL) + EXPOSURE_TOL_S * 1e9


def check_exposures(
    timestamps_ns: np.ndarray, exposures_ns: np.ndarray, where: str, first_line: int = 2
) -> None:
    """Refuse a frame whose exposure exceeds its frame interval (see the module docstring).

    ``timestamps_ns``: (N,) strictly increasing int64 frame stamps; ``exposures_ns``: (N,) int64.
    A single frame has no interval and is not checked.
    """
    t = np.asarray(timestamps_ns, dtype=np.int64)
    e = np.asarray(exposures_ns, dtype=np.int64)
    if t.size < 2:
        return
    d = np.diff(t)
    interval = np.append(d, d[-1])  # frame i: to the next frame; the last: to the previous
    bad = e.astype(np.float64) > max_exposure_ns(interval)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise BoundsError(
            f"{where}: line {k + first_line}: exposure {e[k] * 1e-6:.6g} ms exceeds the frame "
            f"interval {interval[k] * 1e-6:.6g} ms (allowed: interval x "
            f"{1 + EXPOSURE_TOL_REL:g} + {EXPOSURE_TOL_S * 1e3:g} ms, blurtrack/io/bounds.py)"
        )


def check_unique_names(names: list[str], where: str, first_line: int = 2) -> None:
    """Refuse two frames that name one image file."""
    seen: dict[str, int] = {}
    for k, n in enumerate(names):
        if n in seen:
            raise BoundsError(
                f"{where}: line {k + first_line}: image {n} is already the image of line "
                f"{seen[n] + first_line}; every frame needs its own image file"
            )
        seen[n] = k


#: Most trajectory samples per pixel a prediction takes: 4 per px along a 256 px blur, far
#: beyond what a heat map's Bezier fit needs (16 by default).
MAX_TRAJECTORY_SAMPLES = 1024
#: Bytes a prediction holds per evaluated pixel and trajectory sample while it builds one
#: frame's heat maps (x, y and the Bezier fit's float64 work arrays: a generous upper bound).
PREDICT_BYTES_PER_SAMPLE = 128


def memory_bytes() -> int:
    """Physical memory of this machine (bytes); 0 where it cannot be read."""
    import os

    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


def check_memory(need_bytes: float, what: str, sizes: str, hint: str) -> None:
    """Refuse work that needs more than half of this machine's memory, before allocating it
    (:class:`BoundsError` naming the sizes, the estimate and the bound)."""
    have = memory_bytes()
    if have and need_bytes > have // 2:
        raise BoundsError(
            f"{what}: {sizes} need about {need_bytes / 2**30:.3g} GiB, more than half of this "
            f"machine's {have / 2**30:.1f} GiB; {hint}"
        )


def check_prediction_size(
    width: int, height: int, stride: int, samples: int, what: str = "predict"
) -> None:
    """Refuse, before anything is allocated, trajectory samples beyond
    :data:`MAX_TRAJECTORY_SAMPLES` and one frame's heat-map work that would need more than
    half of this machine's memory (:class:`BoundsError`, the bound in the message)."""
    if samples > MAX_TRAJECTORY_SAMPLES:
        raise BoundsError(
            f"{what}: --samples {samples} exceeds {MAX_TRAJECTORY_SAMPLES} trajectory samples "
            "per pixel"
        )
    pixels = -(-int(width) // int(stride)) * -(-int(height) // int(stride))
    check_memory(
        pixels * int(samples) * PREDICT_BYTES_PER_SAMPLE,
        what,
        f"{pixels} pixels x {samples} samples per frame",
        "raise --stride or lower --samples",
    )


#: Bytes ``synth`` holds per output pixel while it makes one triplet (the sharp photo in linear
#: float, the blur accumulator, warp grids, heat maps and their PNG/npy encodings: a generous
#: upper bound), per worker process.
SYNTH_BYTES_PER_PIXEL = 256


def check_synth_size(width: int, height: int, workers: int, what: str = "synth") -> None:
    """Refuse a triplet size whose work in ``workers`` processes needs more than half of this
    machine's memory (:data:`SYNTH_BYTES_PER_PIXEL` per pixel and worker)."""
    pixels = int(width) * int(height)
    check_memory(
        pixels * SYNTH_BYTES_PER_PIXEL * max(1, int(workers)),
        what,
        f"{int(width)}x{int(height)} px triplets in {max(1, int(workers))} worker(s)",
        "lower --size or --workers",
    )


#: Bytes ``simulate`` holds per pixel of a frame while it renders it (float64 accumulators of
#: the exposure's sub-steps, noise and the encoded frame: a generous upper bound), per worker.
SIMULATE_BYTES_PER_PIXEL = 64


def check_simulate_size(width: int, height: int, workers: int, what: str = "simulate") -> None:
    """Refuse a frame size whose rendering in ``workers`` processes needs more than half of
    this machine's memory (:data:`SIMULATE_BYTES_PER_PIXEL` per pixel and worker)."""
    check_memory(
        int(width) * int(height) * SIMULATE_BYTES_PER_PIXEL * max(1, int(workers)),
        what,
        f"{int(width)}x{int(height)} px frames in {max(1, int(workers))} worker(s)",
        "lower the preset's width/height or --workers",
    )


#: Training memory estimate of the GAMD family (gamd.nets): activations kept for the backward
#: pass, float32, per crop pixel and base channel: the three pyramid levels carry c, 2c at 1/4
#: of the pixels and 4c at 1/16 (1.75 c per full-resolution pixel), in about 6 maps per
#: residual unit (Rconv and decoder stacks, conv-ReLU-conv) plus 24 for the encoder, the heat
#: and image inputs, FFMs and decoder heads.
TRAIN_MAPS_PER_RES_UNIT = 6
TRAIN_MAPS_FIXED = 24
#: Bytes per network weight while training: the weight, its gradient and Adam's two moments.
TRAIN_BYTES_PER_WEIGHT = 16


def training_memory_bytes(base_channels: int, num_res: int, batch: int, crop: int | None) -> int:
    """Estimated memory (bytes) of training a GAMD-family network (see the constants above);
    ``crop`` ``None`` (whole images): the weights only."""
    c, r = int(base_channels), int(num_res)
    maps = TRAIN_MAPS_PER_RES_UNIT * r + TRAIN_MAPS_FIXED
    weights = 9 * (4 * c) ** 2 * maps  # 3x3 convolutions at the widest level bound the rest
    need = weights * TRAIN_BYTES_PER_WEIGHT
    if crop is not None:
        need += int(batch) * int(crop) ** 2 * c * 7 // 4 * maps * 4
    return need


def check_training_size(
    base_channels: int, num_res: int, batch: int, crop: int | None, what: str = "gamd train"
) -> None:
    """Refuse a network width/depth, batch and crop whose training needs more than half of this
    machine's memory (:func:`training_memory_bytes`), before the network is built."""
    check_memory(
        training_memory_bytes(base_channels, num_res, batch, crop),
        what,
        f"base_channels {base_channels}, num_res {num_res}, batch {batch}, crop {crop}",
        "lower model base_channels/num_res or data.crop/train.batch_size",
    )
