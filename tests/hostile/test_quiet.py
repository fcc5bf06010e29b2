"""Quiet refusals: every refusal is exactly one non-empty line on stderr, exit 1 or 2, in a
fresh interpreter with stderr not a terminal (so no progress bar may appear), and nothing
before it: no numpy RuntimeWarning, YAML error marker, torch or ffmpeg line, no traceback.
The inputs are left as they were."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.hostile.conftest import World, assert_refused, run_cli, tree_hashes


def _bad_yaml(t: Path) -> None:
    (t / "bad.yaml").write_text("cam0:\n  intrinsics: [1, 2,\n  - oops: {\n")


def _nan_calib(w: World, t: Path) -> None:
    d = yaml.safe_load(w.calib.read_text())
    d["cam0"]["timeshift_cam_imu"] = float("nan")
    (t / "nan.yaml").write_text(yaml.safe_dump(d))


def _other_resolution(w: World, t: Path) -> None:
    d = yaml.safe_load(w.calib.read_text())
    d["cam0"]["resolution"] = [640, 360]  # another aspect: not a scaled calibration
    (t / "other.yaml").write_text(yaml.safe_dump(d))


def _garbage_frame(w: World, t: Path) -> None:
    first = sorted((t / "S" / "cam0" / "data").iterdir())[0]
    first.write_bytes(b"\x89PNG\r\n\x1a\n" + np.random.default_rng(0).bytes(300))


def _nan_gyro(w: World, t: Path) -> None:
    p = t / "S" / "imu0" / "data.csv"
    lines = p.read_text().splitlines()
    parts = lines[5].split(",")
    parts[1] = "nan"
    lines[5] = ",".join(parts)
    p.write_text("\n".join(lines) + "\n")


def _config(w: World, t: Path, **model: object) -> None:
    cfg = w.train_config(**model)
    cfg["train"]["out_dir"] = str(t / "run")  # type: ignore[index]
    (t / "cfg.yaml").write_text(yaml.safe_dump(cfg))


def _write(name: str, data: bytes) -> Callable[[World, Path], None]:
    return lambda w, t: (t / name).write_bytes(data) and None


#: Scratch-folder setups by name.
SETUPS: dict[str, Callable[[World, Path], None]] = {
    "": lambda w, t: None,
    "bad yaml": lambda w, t: _bad_yaml(t),
    "nan calib": _nan_calib,
    "other size": _other_resolution,
    "garbage frame": _garbage_frame,
    "nan gyro": _nan_gyro,
    "garbage video": _write("v.mp4", b"\x00" * 4096),
    "empty folder": lambda w, t: (t / "empty").mkdir(),
    "existing bag": _write("x.bag", b"x"),
    "config": _config,
    "wide config": lambda w, t: _config(w, t, base_channels=1_000_000),
}

#: (case, command line ({S}: a copy of the world's session, {T}: a scratch folder, {synth}:
#: synth with the world's calibration and photos into {T}/ds; ``gamd ...`` runs gamd), setup,
#: text the one line holds)
CASES: list[tuple[str, str, str, str]] = [
    ("validate missing", "validate {T}/nope", "", "not found"),
    ("validate nan gyro", "validate {S}", "nan gyro", ""),
    ("detect missing", "detect {T}/nope --out {T}/t.parquet", "", "not found"),
    ("detect --frames", "detect {S} --frames x:y --out {T}/t.parquet", "", "A:B"),
    ("detect garbage frame", "detect {S} --out {T}/t.parquet --workers 1", "garbage frame", ""),
    ("detect bad params", "detect {S} --params {T}/bad.yaml --out {T}/t.pq", "bad yaml", "YAML"),
    ("detect out in cam0", "detect {S} --out {S}/cam0/t.parquet", "", "recorded"),
    ("calibrate --fit", "calibrate {S} --out {T}/c.yaml --fit fx,zoom", "", "zoom"),
    ("calibrate out in session", "calibrate {S} --out {S}/c.yaml", "", "inside"),
    ("report invalid yaml", "report {S} --calib {T}/bad.yaml --out {T}/r", "bad yaml", "YAML"),
    ("report nan shift", "report {S} --calib {T}/nan.yaml --out {T}/r", "nan calib", ""),
    ("predict other size", "predict {S} --calib {T}/other.yaml --out {T}/p", "other size", "640"),
    ("predict --samples", "predict {S} --calib {calib} --out {T}/p --samples 99999999", "", "1024"),
    ("simulate bad preset", "simulate {T}/sim --preset nope", "", "nope"),
    ("simulate --frames 0", "simulate {T}/sim --frames 0", "", "frames"),
    ("simulate into session", "simulate {S}/sim", "", "inside"),
    ("import missing", "import deepgyro {T}/nope {T}/s", "", ""),
    ("import garbage video", "import video {T}/v.mp4 {T}/s", "garbage video", ""),
    ("synth bad size", "{synth} --size big", "", "WxH"),
    ("synth no photos", "{synth} --images {T}/empty", "empty folder", ""),
    ("synth invalid calib", "{synth} --calib {T}/bad.yaml", "bad yaml", "YAML"),
    ("synth-merge missing", "synth-merge {T}/nope", "", ""),
    ("export storage", "export rosbag {S} {T}/x.bag --storage sqlite3", "", "--ros2"),
    ("export existing", "export rosbag {S} {T}/x.bag", "existing bag", "exists"),
    ("recover missing log", "recover {T}/nope.mcap", "", ""),
    ("gamd train no config", "gamd train --config {T}/nope.yaml", "", "nope.yaml"),
    ("gamd train invalid yaml", "gamd train --config {T}/bad.yaml", "bad yaml", "YAML"),
    ("gamd train width 1e6", "gamd train --config {T}/cfg.yaml", "wide config", "GiB"),
    ("gamd train no dataset", "gamd train --config {T}/cfg.yaml --data {T}/nope", "config", ""),
    ("gamd eval --limit 0", "gamd eval --data {data} --out {T}/ev --limit 0", "", "--limit"),
    ("gamd deblur missing", "gamd deblur {T}/nope --out {T}/o", "", ""),
]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_refusal_is_one_quiet_line(world: World, tmp_path: Path, case: tuple[str, ...]) -> None:
    _, template, setup, needle = case
    s = tmp_path / "S"
    shutil.copytree(world.S, s)
    SETUPS[setup](world, tmp_path)
    synth = "synth --calib {calib} --gyro synthetic --images {images} --out {T}/ds"
    names = {"S": s, "calib": world.calib, "images": world.images, "data": world.data}
    names.update(T=tmp_path)
    argv = template.replace("{synth}", synth).format(**{k: str(v) for k, v in names.items()})
    words = argv.split()
    program = "gamd" if words[0] == "gamd" else "blurtrack"
    before = tree_hashes(tmp_path)
    r = run_cli(program, *words[program == "gamd" :])
    assert_refused(r, needle)
    after = tree_hashes(tmp_path)
    assert {k: after.get(k) for k in before} == before, "an input changed"


def test_there_are_enough_cases() -> None:
    assert len(CASES) >= 20 and len({c[0] for c in CASES}) == len(CASES)
