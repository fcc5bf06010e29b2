"""Size and speed of a network: parameters, MACs and CPU latency at given resolutions."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence

import torch

from gamd.macs import count_parameters, macs_for_size
from gamd.nets import DeblurNet


@torch.inference_mode()
def forward_ms(
    model: DeblurNet,
    height: int,
    width: int,
    repeats: int = 3,
    clock: Callable[[], float] = time.perf_counter,
) -> list[float]:
    """Wall-clock milliseconds of ``repeats`` forward passes on ``(1, 3, H, W)`` (after one
    warm-up pass), on the model's device."""
    device = next(model.parameters()).device
    blur = torch.rand(1, 3, height, width, device=device)
    heat = torch.randn(1, 6, height, width, device=device)
    model.eval()
    model(blur, heat)
    times = []
    for _ in range(repeats):
        t0 = clock()
        model(blur, heat)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        times.append((clock() - t0) * 1e3)
    return times


def profile(
    model: DeblurNet, sizes: Sequence[tuple[int, int]], repeats: int = 3, time_it: bool = True
) -> dict:
    """``{"params": n, "macs": {"HxW": n}, "cpu_ms_median": {"HxW": ms}}`` (sizes as (H, W))."""
    out: dict = {"params": count_parameters(model), "macs": {}, "cpu_ms_median": {}}
    for h, w in sizes:
        key = f"{w}x{h}"
        out["macs"][key] = macs_for_size(model, h, w)
        if time_it:
            out["cpu_ms_median"][key] = statistics.median(forward_ms(model, h, w, repeats))
    return out
