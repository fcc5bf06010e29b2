"""A small demonstration dataset for ``make demo``: a few triplets from the shared backgrounds.

:func:`demo_dataset` blurs BSDS500 photographs with the real GyroDeblurNet shake (synthetic
shake when that file is absent) through a phone-like calibration (or a given one), exact
mode, with mild noise, and returns the build summary. The lead's demo calls it; it prints
nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from blurtrack.errors import SynthesisError
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import Calibration
from blurtrack.synth.dataset import DatasetSpec, build
from blurtrack.synth.photometry import Photometry
from blurtrack.synth.triplet import TripletParams

#: A 720p phone-class camera: 65° horizontal field of view, 20 ms rolling-shutter readout.
DEMO_CALIBRATION = Calibration(Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5), readout_s=0.02))


def demo_dataset(
    out: str | Path,
    data: str | Path,
    count: int = 8,
    size: tuple[int, int] = (320, 180),
    calib: Calibration | None = None,
    workers: int = 1,
) -> dict[str, Any]:
    """Build (or resume) ``out`` from ``data/backgrounds/bsds500``; returns its summary."""
    data = Path(data)
    images = data / "backgrounds" / "bsds500"
    if not images.is_dir():
        raise SynthesisError(f"demo backgrounds not found at {images}")
    shake = data / "real" / "gyrodeblurnet-shake"
    gyro = str(shake.resolve()) if shake.is_dir() else "synthetic:0.7"
    params = TripletParams(
        size=size, exposure_ms=(10.0, 30.0), photometry=Photometry(noise_shot=2e-4, noise_read=2e-3)
    )
    spec = DatasetSpec(
        calib=(calib or DEMO_CALIBRATION).to_dict(),
        gyro=gyro,
        images=str(images.resolve()),
        count=count,
        seed=0,
        params=params,
        group=max(1, count // 2),
    )
    res = build(spec, out, workers=workers)
    return {"out": str(out), "gyro": Path(gyro).name, **res.to_dict()}
