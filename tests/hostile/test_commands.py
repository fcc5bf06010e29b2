"""Hostile input, table-driven: every case names its input class and command, and checks the
contract (docs/robustness.md): the documented exit code, exactly one line on stderr, no
traceback (an uncaught exception fails the test), the input session byte-identical, and no
temporary files left anywhere under the test folder.

Commands run in-process through ``blurtrack.cli.main`` (fast); crash and pipe cases run as
subprocesses in test_process.py.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from blurtrack.cli import main
from blurtrack.io import streaks as streak_table
from blurtrack.io.calibration import write_calibration
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session
from tests.hostile.conftest import debris, tree_hashes

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small laser-grid session with its true streak table, and a calibration beside it."""
    root = tmp_path_factory.mktemp("base")
    s = root / "S"
    write_synthetic_session(s, n_frames=3, resolution=(160, 120), grid=(4, 3))
    session = load_session(s)
    streak_table.write(streak_table.from_truth(session.truth), s / "streaks.parquet")
    write_calibration(session.initial_calibration(), root / "calib.yaml")
    return root


@dataclass
class Env:
    """A fresh copy of the base inputs for one case."""

    root: Path
    S: Path
    calib: Path

    def edit_calib(self, change: Callable[[dict], None], name: str = "bad.yaml") -> Path:
        d = yaml.safe_load(self.calib.read_text())
        change(d["cam0"])
        p = self.root / name
        p.write_text(yaml.safe_dump(d))
        return p

    def edit_streaks(self, change: Callable, name: str = "bad.parquet") -> Path:
        df = streak_table.read(self.S / "streaks.parquet")
        changed = change(df)
        df = df if changed is None else changed
        p = self.root / name
        df.to_parquet(p, index=False)
        return p

    def imu_csv(self, rewrite: Callable[[list[str]], list[str]]) -> None:
        p = self.S / "imu0" / "data.csv"
        p.write_text("\n".join(rewrite(p.read_text().splitlines())) + "\n")


@pytest.fixture
def env(base: Path, tmp_path: Path) -> Env:
    shutil.copytree(base, tmp_path, dirs_exist_ok=True)
    return Env(tmp_path, tmp_path / "S", tmp_path / "calib.yaml")


def _cell(lines: list[str], row: int, col: int, value: str) -> list[str]:
    parts = lines[row].split(",")
    parts[col] = value
    lines[row] = ",".join(parts)
    return lines


def _huge_png(e: Env) -> None:
    import struct
    import zlib

    first = sorted((e.S / "cam0" / "data").iterdir())[0]
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    first.write_bytes(
        b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))
    )


def _no_key(key: str) -> Callable[[dict], None]:
    return lambda c: c.pop(key)


def _set(key: str, value: object) -> Callable[[dict], None]:
    return lambda c: c.__setitem__(key, value)


def _shift_ts(df) -> None:  # type: ignore[no-untyped-def]
    df["timestamp_ns"] += 1


def _far(df) -> None:  # type: ignore[no-untyped-def]
    df.loc[df.index[0], "start_y"] = 1e6


#: (input class, command, setup(env) -> argv, expected exit code, stderr must contain)
CASES: list[tuple[str, str, Callable[[Env], list[str]], int, str]] = [
    # --- outputs into the recorded parts of the session
    (
        "out-into-session",
        "detect",
        lambda e: ["detect", str(e.S), "--out", str(e.S / "imu0" / "data.csv")],
        2,
        "recorded part 'imu0'",
    ),
    (
        "out-into-session",
        "calibrate",
        lambda e: ["calibrate", str(e.S), "--out", str(e.S / "session.yaml")],
        2,
        "recorded part 'session.yaml'",
    ),
    (
        "out-into-session",
        "report",
        lambda e: ["report", str(e.S), "--calib", str(e.calib), "--out", str(e.S / "cam0")],
        2,
        "recorded part 'cam0'",
    ),
    (
        "out-into-session",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.calib),
            "--out",
            str(e.S / "cam0" / "data"),
        ],
        2,
        "recorded part 'cam0'",
    ),
    (
        "out-into-session",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.calib),
            "--out",
            str(e.S / "cam0" / ".." / "truth.yaml"),
        ],
        2,
        "recorded part 'truth.yaml'",
    ),
    (
        "out-into-session",
        "report",
        lambda e: ["report", str(e.S), "--calib", str(e.calib), "--out", str(e.S)],
        2,
        "is a session folder",
    ),
    (
        "out-into-session",
        "simulate",
        lambda e: ["simulate", str(e.S / "imu0" / "new"), "--frames", "1"],
        2,
        "recorded part 'imu0'",
    ),
    (
        "out-into-session",
        "import",
        lambda e: ["import", "deepgyro", str(REAL / "deepgyro-shield"), str(e.S / "cam0" / "x")],
        2,
        "recorded part 'cam0'",
    ),
    (
        "out-into-session",
        "detect --overlay",
        lambda e: [
            "detect",
            str(e.S),
            "--out",
            str(e.root / "t.parquet"),
            "--overlay",
            str(e.S / "cam0" / "data" / "x.png"),
        ],
        2,
        "recorded part 'cam0'",
    ),
    (
        "out-is-input",
        "calibrate",
        lambda e: [
            "calibrate",
            str(e.S),
            "--streaks",
            str(e.S / "streaks.parquet"),
            "--out",
            str(e.S / "streaks.parquet"),
            "--force",
        ],
        2,
        "also an input",
    ),
    (
        "out-via-symlink",
        "predict",
        lambda e: (
            os.symlink(e.S / "imu0", e.root / "L"),
            ["predict", str(e.S), "--calib", str(e.calib), "--out", str(e.root / "L" / "p")],
        )[-1],
        2,
        "recorded part 'imu0'",
    ),
    # --- over an existing result without --force
    (
        "existing-result",
        "calibrate",
        lambda e: ["calibrate", str(e.S), "--out", str(e.calib)],
        2,
        "--force replaces it",
    ),
    (
        "existing-result",
        "detect",
        lambda e: ["detect", str(e.S), "--out", str(e.S / "streaks.parquet")],
        2,
        "--force replaces it",
    ),
    (
        "existing-result",
        "report",
        lambda e: (
            e.root.joinpath("r").mkdir(),
            e.root.joinpath("r", "summary.json").write_text("{}"),
            ["report", str(e.S), "--calib", str(e.calib), "--out", str(e.root / "r")],
        )[-1],
        2,
        "already holds a result",
    ),
    (
        "existing-result",
        "simulate",
        lambda e: ["simulate", str(e.S), "--frames", "1"],
        2,
        "is a session folder",
    ),
    (
        "existing-result",
        "import",
        lambda e: ["import", "deepgyro", str(REAL / "deepgyro-shield"), str(e.root)],
        2,
        "not empty",
    ),
    # --- calibration files
    (
        "calib-missing-T_cam_imu",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.edit_calib(_no_key("T_cam_imu"))),
            "--out",
            str(e.root / "r"),
        ],
        2,
        "lacks the key 'T_cam_imu'",
    ),
    (
        "calib-missing-timeshift",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.edit_calib(_no_key("timeshift_cam_imu"))),
            "--out",
            str(e.root / "p"),
        ],
        2,
        "lacks the key 'timeshift_cam_imu'",
    ),
    (
        "calib-1e300-intrinsics",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.edit_calib(_set("intrinsics", [1e300, 1e300, 80, 60]))),
            "--out",
            str(e.root / "r"),
        ],
        2,
        "out of range",
    ),
    (
        "calib-1e300-intrinsics",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.edit_calib(_set("intrinsics", [1e300, 1e300, 80, 60]))),
            "--out",
            str(e.root / "p"),
        ],
        2,
        "out of range",
    ),
    (
        "calib-nan",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.edit_calib(_set("timeshift_cam_imu", float("nan")))),
            "--out",
            str(e.root / "p"),
        ],
        2,
        "timeshift_cam_imu",
    ),
    (
        "calib-other-resolution",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.edit_calib(_set("resolution", [320, 240]))),
            "--out",
            str(e.root / "r"),
        ],
        2,
        "calibration for 320x240",
    ),
    (
        "calib-not-yaml",
        "report",
        lambda e: (
            e.root.joinpath("x.yaml").write_bytes(b"\xff\xfe: ["),
            ["report", str(e.S), "--calib", str(e.root / "x.yaml"), "--out", str(e.root / "r")],
        )[-1],
        2,
        "not UTF-8 text",
    ),
    (
        "calib-python-tag",
        "predict",
        lambda e: (
            e.root.joinpath("x.yaml").write_text("!!python/object/apply:os.system ['true']\n"),
            ["predict", str(e.S), "--calib", str(e.root / "x.yaml"), "--out", str(e.root / "p")],
        )[-1],
        2,
        "calibration",
    ),
    # --- streak tables
    (
        "streak-y-1e6",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.calib),
            "--streaks",
            str(e.edit_streaks(_far)),
            "--out",
            str(e.root / "r"),
        ],
        2,
        "beyond 65536 px",
    ),
    (
        "streak-y-1e6",
        "calibrate",
        lambda e: [
            "calibrate",
            str(e.S),
            "--streaks",
            str(e.edit_streaks(_far)),
            "--out",
            str(e.root / "c.yaml"),
        ],
        2,
        "beyond 65536 px",
    ),
    (
        "stale-streak-table",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.calib),
            "--streaks",
            str(e.edit_streaks(_shift_ts)),
            "--out",
            str(e.root / "r"),
        ],
        2,
        "do not match",
    ),
    (
        "streak-table-garbage",
        "report",
        lambda e: (
            e.root.joinpath("g.parquet").write_bytes(b"PAR1garbage"),
            [
                "report",
                str(e.S),
                "--calib",
                str(e.calib),
                "--streaks",
                str(e.root / "g.parquet"),
                "--out",
                str(e.root / "r"),
            ],
        )[-1],
        2,
        "not readable Parquet",
    ),
    # --- gyro tables
    (
        "imu-float-timestamp",
        "validate",
        lambda e: (e.imu_csv(lambda L: _cell(L, 5, 0, "1234.5")), ["validate", str(e.S)])[-1],
        2,
        "whole number of nanoseconds",
    ),
    (
        "imu-overflow-timestamp",
        "detect",
        lambda e: (
            e.imu_csv(lambda L: _cell(L, 5, 0, "99999999999999999999999")),
            ["detect", str(e.S), "--out", str(e.root / "t.parquet")],
        )[-1],
        2,
        "within int64",
    ),
    (
        "imu-exponent-timestamp",
        "predict",
        lambda e: (
            e.imu_csv(lambda L: _cell(L, 3, 0, "1e30")),
            ["predict", str(e.S), "--calib", str(e.calib), "--out", str(e.root / "p")],
        )[-1],
        2,
        "whole number",
    ),
    (
        "imu-nan-rate",
        "report",
        lambda e: (
            e.imu_csv(lambda L: _cell(L, 3, 1, "nan")),
            ["report", str(e.S), "--calib", str(e.calib), "--out", str(e.root / "r")],
        )[-1],
        2,
        "not a finite number",
    ),
    (
        "cam-float-timestamp",
        "calibrate",
        lambda e: (
            (e.S / "cam0" / "data.csv").write_text(
                (e.S / "cam0" / "data.csv").read_text().replace("33333333,", "33333333.5,", 1)
            ),
            ["calibrate", str(e.S), "--out", str(e.root / "c.yaml")],
        )[-1],
        2,
        "whole number",
    ),
    # --- images
    (
        "png-header-100000^2",
        "detect",
        lambda e: (_huge_png(e), ["detect", str(e.S), "--out", str(e.root / "t.parquet")])[-1],
        2,
        "100000x100000",
    ),
    (
        "png-header-100000^2",
        "validate",
        lambda e: (_huge_png(e), ["validate", str(e.S)])[-1],
        1,
        "",
    ),
    # --- output folders that cannot be written
    (
        "long-file-name",
        "detect",
        lambda e: ["detect", str(e.S), "--out", str(e.root / ("n" * 246 + ".parquet"))],
        2,
        "longer than 255 bytes",
    ),
    (
        "long-file-name",
        "calibrate",
        lambda e: ["calibrate", str(e.S), "--out", str(e.root / ("n" * 240 + ".yaml"))],
        2,
        "longer than 255 bytes",
    ),
    (
        "out-is-a-file",
        "predict",
        lambda e: ["predict", str(e.S), "--calib", str(e.calib), "--out", str(e.calib), "--force"],
        2,
        "is a file",
    ),
    # --- option values
    (
        "bad-option",
        "predict",
        lambda e: [
            "predict",
            str(e.S),
            "--calib",
            str(e.calib),
            "--out",
            str(e.root / "p"),
            "--grid",
            "1x1",
        ],
        2,
        "--grid",
    ),
    (
        "bad-option",
        "detect",
        lambda e: ["detect", str(e.S), "--out", str(e.root / "t.parquet"), "--frames", "a:b"],
        2,
        "--frames",
    ),
    (
        "bad-option",
        "calibrate",
        lambda e: ["calibrate", str(e.S), "--out", str(e.root / "c.yaml"), "--fit", "bogus"],
        2,
        "bogus",
    ),
    (
        "bad-option",
        "report",
        lambda e: [
            "report",
            str(e.S),
            "--calib",
            str(e.calib),
            "--out",
            str(e.root / "r"),
            "--fit-summary",
            str(e.root / "none.json"),
        ],
        2,
        "not found",
    ),
    # --- missing or malformed sessions
    (
        "no-session",
        "detect",
        lambda e: ["detect", str(e.root / "nope"), "--out", str(e.root / "t.parquet")],
        2,
        "not found",
    ),
    (
        "session-yaml-list",
        "validate",
        lambda e: ((e.S / "session.yaml").write_text("- 1\n- 2\n"), ["validate", str(e.S)])[-1],
        2,
        "mapping",
    ),
    (
        "cam-csv-traversal",
        "validate",
        lambda e: (
            (e.S / "cam0" / "data.csv").write_text(
                "#timestamp [ns],filename,exposure [ns]\n1,../../session.yaml,5\n"
            ),
            ["validate", str(e.S)],
        )[-1],
        2,
        "plain name",
    ),
]


@pytest.mark.parametrize(
    "klass, command, setup, code, needle",
    CASES,
    ids=[f"{c[0]}:{c[1]}" for c in CASES],
)
def test_hostile(
    env: Env,
    capsys: pytest.CaptureFixture[str],
    klass: str,
    command: str,
    setup: Callable[[Env], list[str]],
    code: int,
    needle: str,
) -> None:
    argv = setup(env)
    before = tree_hashes(env.S)
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert rc == code, (klass, command, err)
    assert "Traceback" not in err
    if code == 2:
        assert len(lines) == 1, err
        assert needle in lines[0], lines[0]
    assert tree_hashes(env.S) == before, "the input session changed"
    assert debris(env.root) == []


def test_failed_calibrate_keeps_the_previous_summary(
    env: Env, capsys: pytest.CaptureFixture
) -> None:
    """A fit that fails (a table of one streak) never replaces the good calibration's files."""
    good = {"status": "ok"}
    summary = env.root / "calib.summary.json"
    summary.write_text(str(good))
    one = env.edit_streaks(lambda df: df.iloc[:1])
    keep = tree_hashes(env.root)
    rc = main(["calibrate", str(env.S), "--streaks", str(one), "--out", str(env.calib), "--force"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    after = tree_hashes(env.root)
    assert {k: v for k, v in after.items() if k in keep} == keep
    assert debris(env.root) == []


def test_predict_refuses_non_finite_heat_maps(
    env: Env, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A model that yields NaN (the old 1e300-intrinsics path): refused, no NaN heat map on
    disk, no summary.json, exit 2."""
    from blurtrack.geometry.blur_model import BlurModel

    real = BlurModel.heat_maps

    def nan_maps(self, *a, **k):  # type: ignore[no-untyped-def]
        heat, err = real(self, *a, **k)
        return np.full_like(heat, np.nan), err

    monkeypatch.setattr(BlurModel, "heat_maps", nan_maps)
    rc = main(["predict", str(env.S), "--calib", str(env.calib), "--out", str(env.root / "p")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "not finite" in err, err
    assert list((env.root / "p").rglob("*.npy")) == []
    assert not (env.root / "p" / "summary.json").exists()
    assert debris(env.root) == []


def test_read_only_output(env: Env, readonly_dir: Path, capsys: pytest.CaptureFixture) -> None:
    for argv in (
        ["predict", str(env.S), "--calib", str(env.calib), "--out", str(readonly_dir / "p")],
        ["report", str(env.S), "--calib", str(env.calib), "--out", str(readonly_dir / "r")],
        ["detect", str(env.S), "--out", str(readonly_dir / "t.parquet")],
        ["simulate", str(readonly_dir / "s"), "--frames", "1"],
    ):
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 2 and len(err.splitlines()) == 1 and "not writable" in err, (argv, err)
    assert debris(env.root) == []


def test_full_disk_predict(env: Env, full_dir: Path, capsys: pytest.CaptureFixture) -> None:
    before = tree_hashes(env.S)
    rc = main(["predict", str(env.S), "--calib", str(env.calib), "--out", str(full_dir / "p")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "no space left" in err, err
    assert not (full_dir / "p" / "summary.json").exists()
    assert debris(full_dir) == [] and tree_hashes(env.S) == before


def test_full_disk_import(full_dir: Path, capsys: pytest.CaptureFixture) -> None:
    rc = main(["import", "deepgyro", str(REAL / "deepgyro-shield"), str(full_dir / "s")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "no space left" in err, err
    assert not (full_dir / "s").exists(), "a half session was left behind"
    assert debris(full_dir) == []


def test_malformed_mars_calib(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    src = tmp_path / "mars"
    shutil.copytree(REAL / "marslogger-phone", src)
    for content in (b"not an npz", None):
        if content is None:
            np.savez(src / "calib.npz", mtx=np.ones(5), dist=np.zeros(5))
        else:
            (src / "calib.npz").write_bytes(content)
        rc = main(["import", "marslogger", str(src), str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.splitlines()) == 1 and "calib.npz" in err, err
        assert not (tmp_path / "out").exists()
    assert debris(tmp_path) == []


def test_gamd_deblur_into_the_session(env: Env, capsys: pytest.CaptureFixture) -> None:
    """The issue's case: ``gamd deblur --out S/cam0/data`` replaced a raw frame."""
    from gamd.cli import main as gamd_main

    before = tree_hashes(env.S)
    rc = gamd_main(
        [
            "deblur",
            str(env.S),
            "--checkpoint",
            str(env.root / "none.pt"),
            "--out",
            str(env.S / "cam0" / "data"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1 and "recorded part 'cam0'" in err, err
    assert tree_hashes(env.S) == before and debris(env.root) == []


def test_253_character_names_work(env: Env, capsys: pytest.CaptureFixture) -> None:
    """Long names are written (temporary names stay within 255 bytes), not a traceback."""
    out = env.root / ("p" * 253)
    rc = main(["predict", str(env.S), "--calib", str(env.calib), "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert (out / "summary.json").is_file() and debris(env.root) == []
    table = env.root / ("t" * 240 + ".parquet")  # its .summary.json sibling has 253 bytes
    rc = main(["detect", str(env.S), "--out", str(table)])
    assert rc == 0, capsys.readouterr().err
    assert table.is_file() and debris(env.root) == []


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--samples", "1000000000"], "exceeds 1024 trajectory samples"),
        (["--samples", "1024", "--stride", "1"], None),  # allowed count; memory decides
    ],
)
def test_predict_refuses_absurd_sizes_before_allocating(
    env: Env,
    tmp_path: Path,
    capsys: pytest.CaptureFixture,
    monkeypatch: pytest.MonkeyPatch,
    extra: list[str],
    needle: str | None,
) -> None:
    """``predict --samples 1e9`` once allocated 238 GiB after 13 s: refused at once now, with
    the bound. The memory rule is checked against a machine of 1 GiB (monkeypatched)."""
    from blurtrack.io import bounds

    monkeypatch.setattr(bounds, "memory_bytes", lambda: 2**30)
    before = tree_hashes(env.S)
    out = tmp_path / "p"
    rc = main(["predict", str(env.S), "--calib", str(env.calib), "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert (needle or "more than half of this machine's 1.0 GiB") in err
    assert not (out / "summary.json").exists() and tree_hashes(env.S) == before


def test_prediction_size_bound_lets_the_defaults_through() -> None:
    from blurtrack.io.bounds import check_prediction_size

    check_prediction_size(1920, 1080, 8, 16)  # the defaults on 1080p: a few MB
