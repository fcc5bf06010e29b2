"""Fixtures for the gamd tests: a tiny dataset in the exact `blurtrack synth` layout.

Each example is a smooth random texture blurred by a spatially constant quadratic-Bézier
motion: ``B(x) = mean_t S(x + q(t))`` with ``q(t) = (1-t)² q0 + 2t(1-t) P + t² q1``, and the
heat map holds ``(q0, q1, P)`` at every pixel (DESIGN's definition, pixels).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml


def bezier_blur(sharp: np.ndarray, heat: np.ndarray, n_t: int = 24) -> np.ndarray:
    """Blur ``sharp (H, W, 3)`` float along the per-pixel Bézier of ``heat (6, H, W)``."""
    h, w = sharp.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    acc = np.zeros_like(sharp)
    for t in (np.arange(n_t) + 0.5) / n_t:
        a, b, c = (1 - t) ** 2, 2 * t * (1 - t), t**2
        qx = a * heat[0] + c * heat[2] + b * heat[4]
        qy = a * heat[1] + c * heat[3] + b * heat[5]
        acc += cv2.remap(
            sharp,
            (xs + qx).astype(np.float32),
            (ys + qy).astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )
    return acc / n_t


def random_example(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, ...]:
    """(sharp, blur, heat) with a random texture and a random constant motion."""
    noise = rng.random((h // 4 + 2, w // 4 + 2, 3)).astype(np.float32)
    sharp = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1)
    q0 = rng.uniform(-4, 4, 2)
    q1 = -q0 + rng.uniform(-1, 1, 2)
    p = (q0 + q1) / 2 + rng.uniform(-1.5, 1.5, 2)
    heat = np.empty((6, h, w), np.float32)
    for i, v in enumerate([*q0, *q1, *p]):
        heat[i] = v
    return sharp, bezier_blur(sharp, heat), heat


def write_dataset(
    root: Path,
    counts: dict[str, int],
    size_hw: tuple[int, int] = (40, 48),
    seed: int = 0,
    with_heat: bool = True,
) -> Path:
    """Write a dataset in the `blurtrack synth` layout and return its root."""
    rng = np.random.default_rng(seed)
    manifest = []
    for split, count in counts.items():
        for i in range(count):
            name = f"group{i % 2}"
            stem = f"{i:05d}"
            sharp, blur, heat = random_example(rng, *size_hw)
            folder = root / split / name
            for sub, img in (("sharp", sharp), ("blur", blur)):
                (folder / sub).mkdir(parents=True, exist_ok=True)
                bgr = cv2.cvtColor(
                    (img * 255 + 0.5).clip(0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR
                )
                cv2.imwrite(str(folder / sub / f"{stem}.png"), bgr)
            if with_heat:
                (folder / "heat").mkdir(exist_ok=True)
                np.save(folder / "heat" / f"{stem}.npy", heat)
            manifest.append({"split": split, "name": name, "stem": stem, "seed": seed})
    (root / "manifest.jsonl").write_text("".join(json.dumps(m) + "\n" for m in manifest))
    (root / "dataset.yaml").write_text(yaml.safe_dump({"format": "blurtrack-dataset/1"}))
    return root


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("gamd_ds"), {"train": 6, "test": 3})


@pytest.fixture
def blur_fn():
    return bezier_blur


@pytest.fixture
def make_dataset():
    return write_dataset
