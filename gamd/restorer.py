"""Restoration around a network: the do-no-harm gate and the reduced working resolution.

**Gate (do no harm).** The restored image is ``blur + g · (net(blur) − blur)`` with a per-pixel
gate ``g`` from the heat maps' blur length (:func:`blur_length_px`): ``g = 0`` below
``gate_px[0]``, 1 above ``gate_px[1]``, linear between. Where the heat maps say a pixel is
(almost) still, the output *is* the input, whatever the weights; training applies the same gate
so the network learns what inference does.

**Working resolution.** A small network deblurs blur of a few pixels. For longer blur the image
and its heat maps are brought to a working resolution where the blur is about
``work_blur_px`` long (:func:`working_scale`: factor ``s = p90(L) / work_blur_px``, at least 1),
restored there (heat maps resized and divided by ``s``: displacements in working pixels) and the
restoration's *change* is upsampled and added to the full-size input (gated at full size):
``out = blur + g · up(net(blur_s) − blur_s)``. Training presents the data the same way
(:class:`gamd.data.DeblurDataset` with ``work_blur_px``), so the network only ever sees blur of
about ``work_blur_px``.

**Recentring (rolling shutter).** With a global shutter and the reference time at mid-exposure
every trajectory passes through 0 half-way, ``q(½) = 0``: the blur is centred on the pixel.
With a rolling shutter each row exposes at its own time, so its trajectory is offset by the
motion between its mid-exposure and the reference time: the blurred image is also *displaced*
from the sharp reference, by up to several pixels at the top and bottom rows. A network that
deblurs in place (trained on centred blur) cannot undo that, and the shipped weights made the
demo's rolling-shutter images worse (docs/gamd.md, "Rolling shutter"). :func:`recentre`
resamples the blurred image (and the heat maps) at ``x = y − m(x)`` with ``m`` the Bézier
point at ``τ = ½`` (:func:`centre_offset`), so the blur at ``y`` is centred on ``y`` in the
reference view, then restores as usual. When the largest offset is under
:data:`RECENTRE_MIN_PX` (every global-shutter triplet: there ``m`` is only the Bézier fit
error) nothing is resampled and the result is bit-identical to restoring without it.

**Self-ensemble.** ``ensemble = n`` (1, 2, 4 or 8) runs the network on the first ``n`` of the
eight flips and quarter turns of the working image, with heat maps transformed consistently
(:mod:`gamd.heat`), undoes each transform on the output and averages, before the gate: ``n``
times the network's cost, the same result for a network that is itself equivariant.

Shapes: images ``(B, 3, H, W)`` in [0, 1], heat maps ``(B, 6, H, W)`` in pixels (DESIGN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.nn import functional

from gamd.errors import GamdConfigError
from gamd.heat import hflip, rot90, vflip

#: Working-resolution images keep at least this many pixels on their short side.
MIN_WORK_SIDE = 32
#: Largest centre offset (px) left alone by :func:`recentre`.
RECENTRE_MIN_PX = 0.05
#: Fixed-point iterations of the inverse warp ``x = y − m(x)`` (m is smooth: 3 are plenty).
RECENTRE_ITERS = 3
#: Transforms of the self-ensemble (horizontal flip, vertical flip, quarter turns), applied in
#: that order; the first ``n`` are used for ``ensemble = n``.
ENSEMBLE_TRANSFORMS = (
    (False, False, 0),
    (True, False, 0),
    (False, True, 0),
    (True, True, 0),
    (False, False, 1),
    (True, False, 1),
    (False, True, 1),
    (True, True, 1),
)
ENSEMBLE_SIZES = (1, 2, 4, 8)


def blur_length_px(heat_px: torch.Tensor) -> torch.Tensor:
    """Length (px) of the control polygon q(0) → P → q(1) per pixel, ``(..., 1, H, W)``.

    An upper bound of the Bézier arc length (equal to it for a straight, uniform motion);
    ``heat_px (..., 6, H, W)`` in pixels.
    """
    c = [heat_px[..., i : i + 1, :, :] for i in range(6)]  # q0x q0y q1x q1y px py
    return torch.hypot(c[4] - c[0], c[5] - c[1]) + torch.hypot(c[2] - c[4], c[3] - c[5])


def gate(heat_px: torch.Tensor, gate_px: tuple[float, float]) -> torch.Tensor:
    """Per-pixel gate in [0, 1], ``(..., 1, H, W)``: 0 below ``gate_px[0]`` px of blur, 1 above
    ``gate_px[1]``."""
    lo, hi = gate_px
    return ((blur_length_px(heat_px) - lo) / (hi - lo)).clamp(0.0, 1.0)


def apply_gate(
    restored: torch.Tensor, blur: torch.Tensor, heat_px: torch.Tensor, gate_px: tuple[float, float]
) -> torch.Tensor:
    """``blur + g · (restored − blur)``: exactly ``blur`` where the gate is closed."""
    return blur + gate(heat_px, gate_px) * (restored - blur)


def working_scale(heat_px: torch.Tensor, work_blur_px: float, max_scale: float = math.inf) -> float:
    """Downscaling factor (>= 1) that brings the 90th-percentile blur length of one image's
    ``heat_px (6, H, W)`` to ``work_blur_px``, at most ``max_scale``."""
    length = blur_length_px(heat_px[:, ::4, ::4]).flatten()  # heat maps are smooth
    p90 = float(torch.quantile(length.float(), 0.9)) if length.numel() else 0.0
    return float(min(max(1.0, p90 / work_blur_px), max(1.0, max_scale)))


def centre_offset(heat_px: torch.Tensor) -> torch.Tensor:
    """The Bézier point at ``τ = ½``, ``(q(0) + 2P + q(1)) / 4`` (px), ``(..., 2, H, W)``."""
    return (heat_px[..., 0:2, :, :] + 2 * heat_px[..., 4:6, :, :] + heat_px[..., 2:4, :, :]) / 4


def _sample(x: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """``x (B, C, H, W)`` read bilinearly at pixel positions ``pos (B, 2, H, W)`` (border
    values outside)."""
    h, w = x.shape[-2:]
    gx = pos[:, 0] * (2.0 / max(w - 1, 1)) - 1.0
    gy = pos[:, 1] * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1).to(x.dtype)
    return functional.grid_sample(
        x, grid, mode="bilinear", padding_mode="border", align_corners=True
    )


def recentre(
    images: list[torch.Tensor], heat_px: torch.Tensor
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Blurred images and heat maps (``(B, C, H, W)``, heat in px) resampled so that every
    pixel's blur is centred on it in the reference view (``q(½) = 0``); unchanged when the
    largest offset is under :data:`RECENTRE_MIN_PX`."""
    m = centre_offset(heat_px)
    if float(torch.hypot(m[:, 0], m[:, 1]).max()) < RECENTRE_MIN_PX:
        return images, heat_px
    b, _, h, w = heat_px.shape
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=heat_px.dtype, device=heat_px.device),
        torch.arange(w, dtype=heat_px.dtype, device=heat_px.device),
        indexing="ij",
    )
    y = torch.stack([xx, yy])[None].expand(b, 2, h, w)
    x = y - m
    for _ in range(RECENTRE_ITERS):  # x = y - m(x): where the blur centred on y was recorded
        x = y - _sample(m, x)
    heat = _sample(heat_px, x)
    heat = heat - centre_offset(heat).repeat(1, 3, 1, 1)
    return [_sample(im, x) for im in images], heat


def resize(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Antialiased bilinear resize of ``(B, C, H, W)`` to ``size = (h, w)``."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    down = size[0] < x.shape[-2] or size[1] < x.shape[-1]
    return functional.interpolate(
        x, size=size, mode="bilinear", align_corners=False, antialias=down
    )


def to_working(
    images: list[torch.Tensor], heat_px: torch.Tensor, scale: float
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Images and heat maps (``(B, C, H, W)``) at ``1/scale`` of their size; heat maps divided by
    the actual per-axis factor so they are in working pixels."""
    h, w = heat_px.shape[-2:]
    size = (max(1, round(h / scale)), max(1, round(w / scale)))
    if size == (h, w):
        return images, heat_px
    heat = resize(heat_px, size).clone()
    heat[..., 0::2, :, :] *= size[1] / w
    heat[..., 1::2, :, :] *= size[0] / h
    return [resize(im, size) for im in images], heat


@dataclass(frozen=True)
class RestoreOptions:
    """How inference presents an image to the network (from the run's ``data`` config)."""

    heat_scale_px: float
    work_blur_px: float | None = None
    gate_px: tuple[float, float] | None = None
    #: Resample off-centre (rolling-shutter) blur to the reference view first (:func:`recentre`).
    recentre: bool = True
    #: Self-ensemble size (1: off): average over this many flips/quarter turns.
    ensemble: int = 1

    def __post_init__(self) -> None:
        check_restore_options(self.heat_scale_px, self.work_blur_px, self.gate_px, self.ensemble)
        if self.gate_px is not None:
            object.__setattr__(self, "gate_px", tuple(float(v) for v in self.gate_px))

    @property
    def needs_heat(self) -> bool:
        """Whether the gate or the working scale needs the heat maps."""
        return self.gate_px is not None or self.work_blur_px is not None


def check_restore_options(
    heat_scale_px: float,
    work_blur_px: float | None,
    gate_px: tuple[float, float] | None,
    ensemble: int = 1,
) -> None:
    """Range checks shared by :class:`RestoreOptions` and the data config."""
    if type(ensemble) is not int or ensemble not in ENSEMBLE_SIZES:
        raise GamdConfigError(f"ensemble must be one of {list(ENSEMBLE_SIZES)}, got {ensemble!r}")
    if not (isinstance(heat_scale_px, (int, float)) and math.isfinite(heat_scale_px)):
        raise GamdConfigError(f"heat_scale_px must be a finite number, got {heat_scale_px!r}")
    if heat_scale_px <= 0:
        raise GamdConfigError(f"heat_scale_px must be > 0, got {heat_scale_px!r}")
    if work_blur_px is not None and not (
        isinstance(work_blur_px, (int, float)) and 0.5 <= work_blur_px <= 1000
    ):
        raise GamdConfigError(f"work_blur_px must be in [0.5, 1000] px, got {work_blur_px!r}")
    if gate_px is not None:
        ok = isinstance(gate_px, (list, tuple)) and len(gate_px) == 2
        ok = ok and all(isinstance(v, (int, float)) and math.isfinite(v) for v in gate_px)
        if not ok or not 0 <= gate_px[0] < gate_px[1] <= 100:
            raise GamdConfigError(
                f"gate_px must be [lo, hi] with 0 <= lo < hi <= 100 px, got {gate_px!r}"
            )


def ensemble_forward(
    model: torch.nn.Module, x: torch.Tensor, heat: torch.Tensor | None, ensemble: int = 1
) -> torch.Tensor:
    """The network's finest output for ``x (B, 3, H, W)`` (``heat``: its normalised input or
    None), averaged over the first ``ensemble`` of :data:`ENSEMBLE_TRANSFORMS`."""
    if ensemble == 1:
        return model(x, heat)[0]
    total = torch.zeros_like(x)
    for flip_h, flip_v, turns in ENSEMBLE_TRANSFORMS[:ensemble]:
        xt, ht = x, heat
        if flip_h:
            xt, ht = hflip(xt, ht)
        if flip_v:
            xt, ht = vflip(xt, ht)
        if turns:
            xt, ht = rot90(xt, ht, turns)
        y = model(xt, ht)[0]
        if turns:
            y = torch.rot90(y, -turns, dims=(-2, -1))
        if flip_v:
            y = torch.flip(y, dims=(-2,))
        if flip_h:
            y = torch.flip(y, dims=(-1,))
        total = total + y
    return total / ensemble


@torch.inference_mode()
def restore_image(
    model: torch.nn.Module,
    blur: torch.Tensor,
    heat_px: torch.Tensor | None,
    options: RestoreOptions,
    work: bool = True,
) -> torch.Tensor:
    """Restore ``blur (3, H, W)`` given ``heat_px (6, H, W)`` in pixels; ``(3, H, W)`` in [0, 1].

    ``work=False`` skips the working resolution (restores at full size; for measuring it).
    """
    device = next(model.parameters()).device
    x = blur[None].to(device)
    hp = heat_px[None].to(device) if heat_px is not None else None
    if hp is None and (model.uses_heat or options.needs_heat):
        raise GamdConfigError("this network and its restoration need heat maps")
    scale = 1.0
    if hp is None:  # a heat-free network without gate or working scale: restore as is
        return ensemble_forward(model, x, None, options.ensemble)[0].clamp(0.0, 1.0).cpu()
    if options.recentre:
        (x,), hp = recentre([x], hp)
    if work and options.work_blur_px is not None:
        h, w = x.shape[-2:]
        scale = working_scale(hp[0], options.work_blur_px, min(h, w) / MIN_WORK_SIDE)
    if scale > 1.0:
        (xs,), hs = to_working([x], hp, scale)
    else:
        xs, hs = x, hp
    net_heat = hs / options.heat_scale_px if model.uses_heat else None
    out = ensemble_forward(model, xs, net_heat, options.ensemble)
    if options.gate_px is not None:
        out = apply_gate(out, xs, hs, options.gate_px)
    if scale > 1.0:
        out = x + resize(out - xs, (int(x.shape[-2]), int(x.shape[-1])))
        if options.gate_px is not None:
            out = apply_gate(out, x, hp, options.gate_px)
    return out[0].clamp(0.0, 1.0).cpu()
