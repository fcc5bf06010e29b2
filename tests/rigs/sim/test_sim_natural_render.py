"""The banded natural-scene renderer (rigs.sim.natural_render) against the one-view-at-a-time
reference, its sub-view sum against a much finer exposure integral, the mirrored padding, and
frame-parallel session writing (identical bytes for any number of workers)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rigs.sim.errors import SimError
from rigs.sim.natural import NaturalRig
from rigs.sim.natural_render import pad_texture
from rigs.sim.preset import get_preset
from rigs.sim.writer import CHUNK_FRAMES, rendered_frames, write_session

SMALL = dict(width=320, height=180, focal_px=250.0)
#: Banded vs reference renderer: float32 rounding of the texel coordinates, as a fraction of
#: the scene's electrons per texture unit (measured: <= 6e-5).
TOL_REL = 2e-4
#: Sub-view sum vs an 8x finer one, in 8-bit DN (measured: <= 1.11 DN at 320x180).
SUBVIEW_DN = 1.5


def _dn(rig: NaturalRig) -> float:
    return 255.0 / rig.preset.full_well_e


@pytest.fixture(scope="module", params=["far", "driving"])
def rig(request, shared_data) -> NaturalRig:
    p = get_preset("realistic").replace(**SMALL)
    kw = {} if request.param == "far" else dict(depth_m=5.0, speed_mps=4.0, speed_wobble=0.3)
    return NaturalRig(p, 2, 8, **kw)


def _t(rig: NaturalRig, i: int) -> float:
    return float(rig.frame_times_ns[i]) * 1e-9


def test_banded_renderer_equals_the_reference(rig: NaturalRig) -> None:
    for i in (1, 6):
        t = _t(rig, i)
        fast = rig.render_electrons(t)
        ref = rig.reference_electrons(t)
        assert fast.shape == (180, 320) and fast.dtype == np.float32
        assert np.abs(fast - ref).max() <= TOL_REL * rig._scene_e
        # negative control: the same frame 2 ms later is far outside the tolerance
        late = rig.reference_electrons(t + 2e-3)
        assert np.abs(late - ref).max() > 50 * TOL_REL * rig._scene_e


def test_subview_sum_converges_to_the_exposure_integral(rig: NaturalRig) -> None:
    t = _t(rig, 1)
    n = rig.subviews(t)
    fine = rig.reference_electrons(t, 8 * n)
    err = np.abs(rig.render_electrons(t) - fine).max() * _dn(rig)
    coarse = np.abs(rig.reference_electrons(t, max(2, n // 2)) - fine).max() * _dn(rig)
    assert err <= SUBVIEW_DN
    assert coarse > 1.5 * err  # halving the sub-views is visibly worse


def test_padding_is_one_reflect_period(shared_data) -> None:
    rng = np.random.default_rng(0)
    tex = rng.uniform(size=(13, 21)).astype(np.float32)
    padded, (px, py) = pad_texture(tex)
    assert padded.shape == (13 + 2 * py, 21 + 2 * px)
    # coordinates far beyond the margin, where the padded texture's own mirror takes over
    mx = rng.uniform(-70, 90, (40, 50)).astype(np.float32)
    my = rng.uniform(-50, 60, (40, 50)).astype(np.float32)

    def sample(src: np.ndarray, ox: int, oy: int) -> np.ndarray:
        return cv2.remap(
            src, mx + ox, my + oy, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101
        )

    want = sample(tex, 0, 0)
    assert np.abs(sample(padded, px, py) - want).max() < 1e-5
    # negative control: a margin one texel short of the half period mirrors the wrong way
    # beyond it
    short = cv2.copyMakeBorder(tex, py - 1, py - 1, px - 1, px - 1, cv2.BORDER_REFLECT_101)
    assert np.abs(sample(short, px - 1, py - 1) - want).max() > 0.1


def _digest(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_sessions_are_identical_for_any_worker_count(tmp_path, shared_data) -> None:
    p = get_preset("realistic").replace(width=160, height=90, focal_px=125.0)
    n = 2 * CHUNK_FRAMES + 1  # several chunks, the last one short
    outs = {}
    for w in (1, 2, 3):
        write_session(NaturalRig(p, 4, n), tmp_path / f"w{w}", workers=w)
        outs[w] = _digest(tmp_path / f"w{w}")
    assert len([k for k in outs[1] if k.endswith(".png")]) == n
    assert outs[2] == outs[1] and outs[3] == outs[1]
    # negative control: another seed gives other frames
    other = list(rendered_frames(NaturalRig(p, 5, n), workers=2))
    first = list(rendered_frames(NaturalRig(p, 4, n), workers=1))
    assert not np.array_equal(other[0], first[0])
    with pytest.raises(SimError, match="workers"):
        list(rendered_frames(NaturalRig(p, 4, n), workers=0))


def test_frames_are_shared_across_gyro_rates_only(tmp_path, shared_data) -> None:
    p = get_preset("realistic").replace(width=160, height=90, focal_px=125.0)
    write_session(NaturalRig(p, 4, 5), tmp_path / "a")
    write_session(NaturalRig(p.replace(imu_rate_hz=1000.0), 4, 5), tmp_path / "b")
    write_session(
        NaturalRig(p.replace(imu_rate_hz=1000.0), 4, 5), tmp_path / "c", frames_from=tmp_path / "a"
    )
    b, c = _digest(tmp_path / "b"), _digest(tmp_path / "c")
    assert b == c  # copied frames: the very session rendering gives
    assert _digest(tmp_path / "a")["imu0/data.csv"] != c["imu0/data.csv"]
    with pytest.raises(SimError, match="not what this rig renders"):
        write_session(NaturalRig(p, 6, 5), tmp_path / "d", frames_from=tmp_path / "a")
    with pytest.raises(SimError, match="frame times"):
        write_session(NaturalRig(p, 4, 4), tmp_path / "e", frames_from=tmp_path / "a")


def test_simulate_command_workers(tmp_path, shared_data) -> None:
    from blurtrack.cli import main

    preset = tmp_path / "p.yaml"
    preset.write_text("base: realistic\nwidth: 160\nheight: 90\nfocal_px: 125.0\n")
    argv = ["--target", "natural", "--preset-file", str(preset), "--frames", "6", "--quiet"]
    assert main(["simulate", str(tmp_path / "one"), *argv]) == 0
    assert main(["simulate", str(tmp_path / "two"), *argv, "--workers", "2"]) == 0
    one, two = (_digest(tmp_path / x) for x in ("one", "two"))
    one.pop("summary.json"), two.pop("summary.json")  # timings differ
    assert one == two
    assert main(["simulate", str(tmp_path / "bad"), *argv, "--workers", "0"]) == 2
    assert not (tmp_path / "bad").exists()
