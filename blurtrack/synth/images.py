"""Sharp photographs for synthesis: listing, splitting, fitting to the output size, and the
camera that applies at that size.

* **Listing**: every ``.jpg/.jpeg/.png`` under the image folder (recursively, sorted, hidden
  files and links out of the folder skipped), addressed by their path relative to it.
* **Split**: an image whose relative path has a ``test`` component (BSDS500's ``test/``) goes to
  the ``test`` split, every other image (``train/``, ``val/``) to ``train``; one image never
  lands in both.
* **Fitting**: the photograph is scaled to *cover* the output size keeping its aspect ratio
  (cubic upscaling, area downscaling), then cropped at a seeded position. Photographs smaller
  than ``--size`` (BSDS500 is 481×321) are therefore upscaled, unless ``--no-upscale`` asks to
  refuse them. Upscaled photos are softer than native ones; the triplet is still consistent
  because the blur is made from the very sharp image that is stored.
* **Camera**: the calibration's camera is scaled to cover the output size and centre-cropped
  (:func:`camera_for_size`): same focal length in units of the sensor, same field of view
  along the tighter axis, principal point moved with the crop, same distortion (it acts on
  normalised coordinates) and the same full-frame readout time.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from blurtrack.errors import SynthesisError
from blurtrack.geometry.camera import Camera
from blurtrack.io.images import ImageError, read_image

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
#: Largest accepted source photograph (pixels), checked before decoding fully.
MAX_PIXELS = 80_000_000


def list_images(folder: str | Path) -> list[str]:
    """Relative POSIX paths of the photographs under ``folder``, sorted."""
    root = Path(folder)
    if not root.is_dir():
        raise SynthesisError(f"image folder not found: {root}")
    base = root.resolve()
    out = []
    for p in root.rglob("*"):
        rel = p.relative_to(root)
        if (
            any(part.startswith(".") for part in rel.parts)
            or p.suffix.lower() not in IMAGE_SUFFIXES
            or not p.is_file()
        ):
            continue
        if not p.resolve().is_relative_to(base):
            continue  # a link leading out of the folder
        out.append(rel.as_posix())
    if not out:
        raise SynthesisError(f"no .jpg/.png photographs under {root}")
    return sorted(out)


def split_of(rel_path: str) -> str:
    """``test`` for images under a ``test`` folder, else ``train``."""
    return "test" if "test" in Path(rel_path).parts[:-1] else "train"


def load_image(folder: str | Path, rel_path: str) -> np.ndarray:
    """Decode an 8-bit 3-channel image (BGR order, as OpenCV stores it)."""
    rel = Path(rel_path)
    if rel.is_absolute() or ".." in rel.parts:
        raise SynthesisError(f"image path {rel_path!r} must stay inside {folder}")
    p = Path(folder) / rel
    try:
        return read_image(p, cv2.IMREAD_COLOR, MAX_PIXELS, "photograph")
    except ImageError as exc:
        raise SynthesisError(str(exc)) from None


def fit_to_size(
    img: np.ndarray, width: int, height: int, rng: np.random.Generator, upscale: bool = True
) -> tuple[np.ndarray, dict]:
    """Scale ``img`` to cover ``width x height`` and crop at a seeded position.

    Returns the fitted uint8 image and ``{"scale", "crop_xy"}`` for the manifest.
    """
    h, w = img.shape[:2]
    scale = max(width / w, height / h)
    if scale > 1 and not upscale:
        raise SynthesisError(
            f"image is {w}x{h}, smaller than the output {width}x{height} (upscaling disabled)"
        )
    sw, sh = max(width, round(w * scale)), max(height, round(h * scale))
    if (sw, sh) != (w, h):
        interp = cv2.INTER_CUBIC if scale > 1 else cv2.INTER_AREA
        img = cv2.resize(img, (sw, sh), interpolation=interp)
    x0 = int(rng.integers(0, sw - width + 1))
    y0 = int(rng.integers(0, sh - height + 1))
    out = np.ascontiguousarray(img[y0 : y0 + height, x0 : x0 + width])
    return out, {"scale": float(scale), "crop_xy": [x0, y0]}


def camera_for_size(camera: Camera, width: int, height: int) -> Camera:
    """The calibrated camera scaled to cover ``width x height`` and centre-cropped to it.

    >>> cam = Camera((1280, 720), (1000.0, 1000.0, 639.5, 359.5))
    >>> camera_for_size(cam, 640, 360).intrinsics
    (500.0, 500.0, 319.5, 179.5)
    """
    W, H = camera.resolution
    factor = max(width / W, height / H)
    fx, fy, cx, cy = camera.intrinsics
    # Pixel-centre convention: a point at x maps to (x + 0.5) * factor - 0.5, then the crop.
    ox = (W * factor - width) / 2
    oy = (H * factor - height) / 2
    return replace(
        camera,
        resolution=(width, height),
        intrinsics=(
            fx * factor,
            fy * factor,
            (cx + 0.5) * factor - 0.5 - ox,
            (cy + 0.5) * factor - 0.5 - oy,
        ),
    )
