"""``blurtrack simulate`` end to end, and what the hard preset promises."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.io.session import load_session
from rigs.sim.preset import get_preset
from rigs.sim.rig import SimRig
from rigs.sim.shake import default_shake_path

SHAKE = default_shake_path()


def test_cli_writes_session_truth_and_summary(tmp_path: Path, capsys) -> None:
    out = tmp_path / "s"
    rc = main(["simulate", str(out), "--preset", "clean", "--frames", "3", "--seed", "2"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "simulated 3 frames (clean, seed 2)" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3 and summary["streaks"] > 300
    s = load_session(out)
    assert len(s.frames) == 3 and s.truth["simulator"]["seed"] == 2
    assert s.meta.extra["rig"] == {"kind": "simulated", "preset": "clean", "seed": 2}


def test_cli_preset_file_and_overrides(tmp_path: Path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text(
        "base: realistic\nname: tiny\nwidth: 320\nheight: 240\nfocal_px: 250.0\n"
        "dot_cols: 5\ndot_rows: 4\n"
    )
    out = tmp_path / "s"
    rc = main(
        [
            "simulate",
            str(out),
            "--preset-file",
            str(f),
            "--frames",
            "2",
            "--motion",
            "synthetic",
            "--bit-depth",
            "16",
            "--imu-rate",
            "500",
        ]
    )
    assert rc == 0
    s = load_session(out)
    assert s.read_image(0).dtype == np.uint16
    assert s.meta.imu.rate_hz == 500.0
    assert s.truth["simulator"]["preset"]["name"] == "tiny"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "nope"], "unknown preset"),
        (["--frames", "0"], "frames"),
        (["--preset", "realistic", "--shake", "/nonexistent/g.txt"], "shake trace not found"),
    ],
)
def test_cli_errors_are_one_line_exit_2(tmp_path: Path, capsys, args, message) -> None:
    rc = main(["simulate", str(tmp_path / "s"), *args])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1


def test_cli_refuses_a_non_empty_folder(tmp_path: Path, capsys) -> None:
    (tmp_path / "keep.txt").write_text("precious")
    rc = main(["simulate", str(tmp_path), "--preset", "clean", "--frames", "1"])
    assert rc == 2 and "not empty" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").read_text() == "precious"


def crossing(p: np.ndarray, q: np.ndarray) -> bool:
    """Whether polylines ``p (n, 2)`` and ``q (m, 2)`` properly intersect."""
    a, b = p[:-1, None], p[1:, None]
    c, d = q[None, :-1], q[None, 1:]

    def cross(o, u, v):
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (
            v[..., 0] - o[..., 0]
        )

    return bool(
        np.any((cross(c, d, a) * cross(c, d, b) < 0) & (cross(a, b, c) * cross(a, b, d) < 0))
    )


@pytest.mark.skipif(not SHAKE.is_file(), reason=f"shake traces absent: {SHAKE}")
def test_hard_preset_has_fast_shake_saturation_crossings_and_leaving_dots() -> None:
    rig = SimRig(get_preset("hard"), 3, 10)
    crossings = leaving = saturated = 0
    lengths = []
    for i in (2, 6):
        t = rig.frame_times_ns[i] * 1e-9
        s = rig.streaks(t)
        vis = np.flatnonzero(s.visible)
        leaving += int(np.sum(s.visible & ~s.inside))
        lengths.extend(s.length_px[vis])
        coarse = s.path[:, ::8]
        for a in vis:
            for b in vis:
                if (
                    a < b
                    and np.linalg.norm(s.ref[a] - s.ref[b]) < 250
                    and crossing(coarse[a], coarse[b])
                ):
                    crossings += 1
        saturated += int(np.count_nonzero(rig.render_frame(t) == 255))
    assert np.median(lengths) > 40
    assert crossings > 5 and leaving > 20 and saturated > 1000
