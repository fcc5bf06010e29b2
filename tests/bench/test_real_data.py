"""The short form of bench/real_data.py (issue 44, item 5): the real phone video, imported and
calibrated with the user's two commands, still calibrates, decides its axes clearly and keeps
its hold-out error; a recording that calibrates today cannot silently stop calibrating."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from blurtrack.testing.bench_script import load_bench_script


@pytest.fixture(scope="module")
def quick(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    bench = load_bench_script("real_data")
    out = tmp_path_factory.mktemp("real_data")
    assert bench.main(["--quick", "--out", str(out / "pics"), "--json", str(out / "r.json")]) == 0
    recs = json.loads((out / "r.json").read_text())
    assert [r["item"] for r in recs] == ["phone-video-412hz"]
    return recs[0]


def test_phone_video_calibrates_with_a_clear_axis_decision(quick: dict) -> None:
    assert quick["outcome"] == "calibrated", quick["outcome"]
    assert [s["rc"] for s in quick["steps"]] == [0, 0]
    f = quick["figures"]
    assert f["status"] == "ok"
    assert f["axes_margin"] >= 2.0
    assert f["holdout_median_px"] <= 0.35
    # the pure-rotation model does not decide a drive; the common heading does, and the
    # translation fit then starts from the axis search only
    assert f["axes_model"] == "common heading" and f["translation"] == "travel"
    assert f["translation_starts"].startswith("axis search only")


def test_phone_video_offset_and_readout_have_finite_positive_sigmas(quick: dict) -> None:
    f = quick["figures"]
    for key in ("timeshift", "readout"):
        assert math.isfinite(f[f"{key}_ms"])
        sigma = f[f"{key}_sigma_ms"]
        assert sigma is not None and math.isfinite(sigma) and sigma > 0


def test_quick_form_writes_the_overlays_outside_the_data(quick: dict, shared_data: Path) -> None:
    pics = [Path(p) for p in quick["pictures"]]
    assert len(pics) == 2 and all(p.is_file() for p in pics)
    assert not any(p.resolve().is_relative_to(shared_data.resolve()) for p in pics)
    assert "halves" not in quick


# The bench's helpers, without the data.


def test_agreement_is_two_sigma_of_the_difference() -> None:
    bench = load_bench_script("real_data")
    assert bench.agree(1.0, 0.3, 1.0 + 2 * 0.5, 0.4)  # |diff| = 2 * sqrt(0.3^2 + 0.4^2)
    assert not bench.agree(1.0, 0.3, 1.0 + 2 * 0.5 + 1e-9, 0.4)


def test_half_layout_links_the_chosen_frames_and_the_same_time_files(tmp_path: Path) -> None:
    bench = load_bench_script("real_data")
    src = tmp_path / "src"
    (src / "frames").mkdir(parents=True)
    for k in range(100, 106):
        (src / "frames" / f"RE_frame-{k}.jpg").write_bytes(b"x")
    for name in ("framestamp.txt", "gyro.txt"):
        (src / name).write_text(name)
    lay = bench.phone_half_layout(src, tmp_path / "half", 101, 103)
    assert sorted(p.name for p in (lay / "frames").iterdir()) == [
        "RE_frame-101.jpg",
        "RE_frame-102.jpg",
        "RE_frame-103.jpg",
    ]
    assert all(p.is_symlink() for p in (lay / "frames").iterdir())
    assert (lay / "gyro.txt").resolve() == (src / "gyro.txt").resolve()
    assert (lay / "framestamp.txt").read_text() == "framestamp.txt"


def test_a_refused_command_gives_its_exit_code_and_one_line_error(tmp_path: Path) -> None:
    bench = load_bench_script("real_data")
    rec = bench.run_cli(["validate", str(tmp_path / "no-such-session")])
    assert rec["rc"] == 2
    assert rec["error"] and "\n" not in rec["error"]
    assert not rec["error"].startswith("blurtrack")
