"""The held-out preset variants shipped in ``configs/sim`` (docs/detection.md) load, and each
differs from its base in what its comment says it changes."""

from __future__ import annotations

from pathlib import Path

import pytest

from blurtrack.io.yamlio import read_yaml
from rigs.sim.preset import SimPreset, get_preset

VARIANTS = sorted((Path(__file__).resolve().parents[3] / "configs" / "sim").glob("*.yaml"))


def test_the_variants_are_found() -> None:
    assert len(VARIANTS) >= 8
    assert {"hard_long_dense_grid.yaml", "dense_long_grid.yaml"} <= {p.name for p in VARIANTS}


@pytest.mark.parametrize("path", VARIANTS, ids=lambda p: p.stem)
def test_a_variant_loads_named_for_its_file_and_changes_its_base(path: Path) -> None:
    raw = read_yaml(path, "preset file")
    preset = SimPreset.from_yaml(path)
    assert preset.name == path.stem
    base = get_preset(str(raw["base"]))
    changed = {k for k in raw if k not in ("base", "name")}
    assert changed, "a variant changes at least one trait"
    for key in changed:
        assert getattr(preset, key) != getattr(base, key), key


def test_the_long_dense_variant_is_both_of_its_parents() -> None:
    by = {p.stem: SimPreset.from_yaml(p) for p in VARIANTS}
    both, long_, dense = by["hard_long_dense_grid"], by["hard_long_exposure"], by["hard_dense_grid"]
    assert (both.exposure_s, both.fps) == (long_.exposure_s, long_.fps)
    assert (both.dot_cols, both.dot_rows) == (dense.dot_cols, dense.dot_rows)
