"""Heat-map normalisation and the geometric augmentations that keep heat maps consistent.

Heat maps follow DESIGN: ``(6, H, W)`` float32, pixels at the image's resolution; channels
(0, 1) = q(0) (x, y), (2, 3) = q(1), (4, 5) = Bézier control point, where the blurred pixel x
collects the sharp image at ``x + q(t)``.

Normalisation: the networks see ``heat / scale_px`` with a fixed ``scale_px`` (default 16 px,
the order of a typical blur length) stored in the training config and the checkpoint, so
inference divides by the same number. A fixed scale (not per-image statistics) keeps the map
a linear function of the motion, which is what the network must learn to undo.

Augmentations act on ``(C, H, W)`` tensors; the displacement vectors transform with the image:
a horizontal flip negates the x components, a vertical flip the y components, and a rotation
by 90° (``torch.rot90(k=1)`` on the last two axes, i.e. ``np.rot90``) maps a displacement
``(dx, dy)`` to ``(dy, -dx)``.
"""

from __future__ import annotations

import torch

from gamd.errors import GamdConfigError

#: Default normalisation scale of heat maps, pixels.
DEFAULT_HEAT_SCALE_PX = 16.0
X_CHANNELS = (0, 2, 4)
Y_CHANNELS = (1, 3, 5)


def normalise_heat(heat_px: torch.Tensor, scale_px: float) -> torch.Tensor:
    """Heat maps in pixels -> network input (``heat_px / scale_px``)."""
    if not scale_px > 0:
        raise GamdConfigError(f"heat_scale_px must be > 0, got {scale_px!r}")
    return heat_px / float(scale_px)


def hflip(
    image: torch.Tensor, heat: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Mirror left-right; heat x components change sign."""
    image = torch.flip(image, dims=(-1,))
    if heat is not None:
        heat = torch.flip(heat, dims=(-1,)).clone()
        heat[..., X_CHANNELS, :, :] *= -1
    return image, heat


def vflip(
    image: torch.Tensor, heat: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Mirror top-bottom; heat y components change sign."""
    image = torch.flip(image, dims=(-2,))
    if heat is not None:
        heat = torch.flip(heat, dims=(-2,)).clone()
        heat[..., Y_CHANNELS, :, :] *= -1
    return image, heat


def rot90(
    image: torch.Tensor, heat: torch.Tensor | None = None, k: int = 1
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Rotate by ``k`` quarter turns as ``np.rot90``; displacements ``(dx, dy) -> (dy, -dx)``
    per quarter turn."""
    k = k % 4
    image = torch.rot90(image, k, dims=(-2, -1))
    if heat is not None:
        heat = torch.rot90(heat, k, dims=(-2, -1))
        for _ in range(k):
            dx, dy = heat[..., X_CHANNELS, :, :], heat[..., Y_CHANNELS, :, :]
            out = torch.empty_like(heat)
            out[..., X_CHANNELS, :, :] = dy
            out[..., Y_CHANNELS, :, :] = -dx
            heat = out
    return image, heat


def augment(
    images: list[torch.Tensor],
    heat: torch.Tensor | None,
    flip_h: bool,
    flip_v: bool,
    quarter_turns: int,
) -> tuple[list[torch.Tensor], torch.Tensor | None]:
    """Apply the same flips and rotation to every image and, consistently, to the heat maps."""
    if not images:
        raise GamdConfigError("augment needs at least one image")
    outs = []
    for i, im in enumerate(images):
        h = heat if i == 0 else None
        if flip_h:
            im, h = hflip(im, h)
        if flip_v:
            im, h = vflip(im, h)
        if quarter_turns:
            im, h = rot90(im, h, quarter_turns)
        if i == 0:
            heat = h
        outs.append(im)
    return outs, heat
