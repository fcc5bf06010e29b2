"""Benchmark scripts loaded as modules (``blurtrack.testing.bench_script``)."""

from __future__ import annotations

import sys

import pytest

from blurtrack.testing.bench_script import BENCH_DIR, load_bench_script


def test_a_script_loads_with_its_siblings_importable() -> None:
    mod = load_bench_script("json_out")
    assert callable(mod.emit)
    assert str(BENCH_DIR) in sys.path
    # A script that imports a sibling (bench_detect) loads as when run.
    seeds = load_bench_script("crossframe_seeds")
    assert seeds.match.__module__ == "bench_detect"


def test_a_missing_script_is_refused() -> None:
    with pytest.raises(FileNotFoundError, match="no_such_script"):
        load_bench_script("no_such_script")
