"""bench/natural_trust.py: no confident streak on the real recordings' natural frames (lamps,
lit windows, headlights, screens; no laser dots), and the detector sees what is there."""

from __future__ import annotations

from pathlib import Path

import pytest

from blurtrack.testing.bench_script import load_bench_script


@pytest.mark.parametrize("name", ["deepgyro-shield", "marslogger-phone", "phone-video-412hz"])
def test_no_quality_ok_streak_on_a_natural_frame(shared_data: Path, name: str) -> None:
    bench = load_bench_script("natural_trust")
    got = bench.recording(name, every=3)
    assert got["frames"] >= 3
    # Not a vacuous zero: the frames have light the detector measures (and calls extended).
    assert got["detections"] >= 2 * got["frames"]
    assert got["source"].get("extended", 0) > 0
    assert got["quality_ok"] == 0, got["reason"]
