"""bench/bench_detect.py: the whole-command timing passes the detection options on."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

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
