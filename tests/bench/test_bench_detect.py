"""bench/bench_detect.py: the whole-command timing passes the detection options on."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd
import pytest

from blurtrack.testing.bench_script import load_bench_script


def _timed_commands(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, **options: Any
) -> tuple[list[list[str]], dict[str, Any]]:
    """The commands ``command_speed`` runs (subprocesses replaced by a recorder that writes
    a two-row table where the command would) and its result."""
    bench = load_bench_script("bench_detect")
    session = SimpleNamespace(frames=[0, 1], image_path=lambda i: tmp_path / f"{i}.png")
    monkeypatch.setattr(bench, "load_session", lambda folder: session)
    monkeypatch.setattr(bench, "baseline_files", lambda paths: None)
    seen: list[list[str]] = []

    def run(cmd: list[str], **kw: Any) -> None:
        seen.append(list(cmd))
        out = Path(cmd[cmd.index("--out") + 1])
        pd.DataFrame({"frame": [0, 1]}).to_parquet(out)

    monkeypatch.setattr(bench.subprocess, "run", run)
    res = bench.command_speed(tmp_path / "session", 2, tmp_path, **options)
    return seen, res


def test_params_and_gyro_go_to_every_timed_command(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("gyro_template: false\n")
    before = tmp_path / "before"
    seen, res = _timed_commands(monkeypatch, tmp_path, before=before, params=params, gyro="off")
    assert len(seen) == 2 * 4  # two repeats of four variants
    for cmd in seen:
        assert cmd[cmd.index("--params") + 1] == str(params.resolve())
        assert cmd[cmd.index("--gyro") + 1] == "off"
    assert res["params"] == str(params) and res["gyro"] == "off"
    assert res["streaks_per_frame"] == 1.0


def test_without_params_the_commands_take_the_defaults(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    seen, res = _timed_commands(monkeypatch, tmp_path)
    assert len(seen) == 2 * 2
    assert all("--params" not in cmd for cmd in seen)
    assert all(cmd[cmd.index("--gyro") + 1] == "auto" for cmd in seen)
    assert res["params"] is None


def test_a_preset_file_is_simulated_by_its_text(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    bench = load_bench_script("bench_detect")
    seen: list[list[str]] = []
    monkeypatch.setattr(bench.subprocess, "run", lambda cmd, **kw: seen.append(list(cmd)))
    preset = tmp_path / "long.yaml"
    preset.write_text("base: hard\nexposure_s: 0.06\nfps: 15.0\n")
    first = bench.simulate(tmp_path / "work", str(preset), 4, 7)
    assert first.name.startswith("long-") and first.name.endswith("-s7-f4")
    assert seen[-1][seen[-1].index("--preset-file") + 1] == str(preset.resolve())
    assert "--preset" not in seen[-1]
    # An edited file is another session; a built-in name is passed as --preset (the control).
    preset.write_text("base: hard\nexposure_s: 0.05\nfps: 15.0\n")
    assert bench.simulate(tmp_path / "work", str(preset), 4, 7) != first
    assert bench.simulate(tmp_path / "work", "hard", 4, 7).name == "hard-s7-f4"
    assert seen[-1][seen[-1].index("--preset") + 1] == "hard"


def _corner_truth(chromatic_px: float) -> dict[str, Any]:
    """One true streak near the top-left corner of a 1280 x 720 frame of a red-laser colour
    sensor with ``chromatic_px`` of lateral colour."""
    preset = {
        "width": 1280,
        "height": 720,
        "chromatic_px": chromatic_px,
        "colour_response": [1.0, 0.18, 0.06],
    }
    streak = {"start": [20.0, 20.0], "end": [40.0, 30.0], "inside": True}
    return {"simulator": {"preset": preset}, "frames": [{"index": 0, "streaks": [streak]}]}


def test_the_lights_geometry_is_the_truth_magnified_by_its_lateral_colour() -> None:
    bench = load_bench_script("bench_detect")
    assert bench.light_magnification(_corner_truth(0.0)) is None
    assert bench.light_magnification({"frames": []}) is None
    mag = bench.light_magnification(_corner_truth(1.0))
    # Derived: luma weights times the red laser's response, R 0.299, G 0.1057, B 0.00684.
    w_r, w_g, w_b = 0.299 * 1.0, 0.587 * 0.18, 0.114 * 0.06
    r_corner = float(np.hypot(639.5, 359.5))
    assert mag == pytest.approx(1.0 + (w_r - w_b) / (w_r + w_g + w_b) / r_corner)
    # A detection where the light is (magnified about the centre): right against the light,
    # wrong against the lens's geometry once the shift passes the 2 px gate.
    truth = _corner_truth(4.0)
    m = bench.light_magnification(truth)
    c = np.array([639.5, 359.5])
    a, b = c + (np.array([20.0, 20.0]) - c) * m, c + (np.array([40.0, 30.0]) - c) * m
    assert np.hypot(*(a - [20.0, 20.0])) > 2.0
    table = pd.DataFrame(
        {
            "frame": [0],
            "start_x": [a[0]],
            "start_y": [a[1]],
            "end_x": [b[0]],
            "end_y": [b[1]],
            "quality_ok": [True],
        }
    )
    got = bench.trust(table, truth)
    assert got["ok_wrong"] == 1 and got["ok_wrong_light"] == 0
    assert got["ok_precision_light"] == 1.0
    # Without lateral colour there is no second figure.
    assert "ok_precision_light" not in bench.trust(table, _corner_truth(0.0))
