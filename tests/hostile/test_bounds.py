"""Physical bounds at load and on write (blurtrack/io/bounds.py): an absurd gyro rate, an
exposure longer than the frame interval, two frames naming one image file. Each is refused
with one line on stderr naming the bound, exit 2, and the input left as it was."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.errors import BoundsError, SessionError
from blurtrack.geometry.camera import Camera
from blurtrack.io import bounds
from blurtrack.io.calibration import write_calibration
from blurtrack.io.session import SessionMeta, SessionWriter, load_session
from blurtrack.testing.mini_session import write_synthetic_session
from tests.hostile.conftest import debris, tree_hashes

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic session (30 fps, 12 ms exposures) and its initial calibration."""
    root = tmp_path_factory.mktemp("bounds")
    write_synthetic_session(root / "S", n_frames=3, resolution=(96, 72), grid=(3, 2))
    write_calibration(load_session(root / "S").initial_calibration(), root / "calib.yaml")
    return root


@pytest.fixture
def env(base: Path, tmp_path: Path) -> Path:
    shutil.copytree(base, tmp_path / "e")
    return tmp_path / "e"


def _edit_csv(path: Path, line: int, column: int, value: str) -> None:
    """Replace one field (1-based line, 0-based column) of a CSV table."""
    lines = path.read_text().splitlines()
    fields = lines[line - 1].split(",")
    fields[column] = value
    lines[line - 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


def _refused(args: list[str], root: Path, capsys: pytest.CaptureFixture, *words: str) -> str:
    before = tree_hashes(root / "S")
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1, (rc, err)
    for w in words:
        assert w in err, err
    assert tree_hashes(root / "S") == before and debris(root) == []
    return err


def test_bounds_are_physical() -> None:
    # far above the largest gyro full scale (2000 deg/s = 35 rad/s), below absurdity
    assert np.deg2rad(2000) < bounds.MAX_GYRO_RADPS <= 200
    bounds.check_gyro(np.array([[35.0, 0.0, 0.0], [0.0, -60.0, 70.0]]), "x")
    with pytest.raises(BoundsError, match=r"line 3: gyro rate 1e\+308 rad/s exceeds .* 100 rad/s"):
        bounds.check_gyro(np.array([[0.0, 0, 0], [1e308, 0, 0]]), "x")
    with pytest.raises(BoundsError, match="1.41421e\\+308 rad/s"):  # no overflow to inf
        bounds.check_gyro(np.array([[1e308, 1e308, 0]]), "x")
    bounds.check_accel(np.array([[0.0, 0.0, 9.81 * 400]]), "x")  # a high-g part
    # the MARS clip: 240 ms exposures at 240.03 ms intervals pass
    t = np.cumsum(np.full(10, 240_026_302))
    bounds.check_exposures(t, np.full(10, 240_000_000), "x")
    with pytest.raises(BoundsError, match="exposure 10000 ms exceeds the frame interval 33.3"):
        bounds.check_exposures(np.array([0, 33_333_333]), np.array([10**10, 10**7]), "x")
    with pytest.raises(BoundsError, match="line 3: exposure"):  # the last frame: interval before
        bounds.check_exposures(np.array([0, 33_333_333]), np.array([10**7, 10**8]), "x")
    with pytest.raises(BoundsError, match="line 4: image a.png is already the image of line 2"):
        bounds.check_unique_names(["a.png", "b.png", "a.png"], "x")


def test_an_absurd_gyro_rate_is_refused_by_validate_and_predict(
    env: Path, capsys: pytest.CaptureFixture
) -> None:
    _edit_csv(env / "S" / "imu0" / "data.csv", 5, 2, "1e308")
    with pytest.raises(BoundsError):
        load_session(env / "S")
    _refused(["validate", str(env / "S")], env, capsys, "line 5", "100 rad/s")
    out = env / "p"
    args = ["predict", str(env / "S"), "--calib", str(env / "calib.yaml"), "--out", str(out)]
    _refused(args, env, capsys, "gyro rate 1e+308 rad/s")
    assert not out.exists()


def test_an_exposure_longer_than_the_frame_interval_is_refused(
    env: Path, capsys: pytest.CaptureFixture
) -> None:
    cam = env / "S" / "cam0" / "data.csv"
    for line in (2, 3, 4):
        _edit_csv(cam, line, 2, str(10 * 10**9))  # 10 s at 30 fps
    _refused(["validate", str(env / "S")], env, capsys, "exposure 10000 ms", "frame interval")
    out = env / "p"
    args = ["predict", str(env / "S"), "--calib", str(env / "calib.yaml"), "--out", str(out)]
    err = _refused(args, env, capsys, "exposure 10000 ms")
    assert "nan" not in err and not out.exists()


def test_two_frames_naming_one_image_are_refused(env: Path, capsys: pytest.CaptureFixture) -> None:
    cam = env / "S" / "cam0" / "data.csv"
    first = cam.read_text().splitlines()[1].split(",")[1]
    _edit_csv(cam, 3, 1, first)
    _refused(["validate", str(env / "S")], env, capsys, "line 3", f"image {first} is already")


def test_the_writer_refuses_what_the_loader_would(tmp_path: Path) -> None:
    meta = SessionMeta(Camera((4, 3), (2.0, 2.0, 1.5, 1.0)))
    img = np.zeros((3, 4), np.uint8)
    with pytest.raises(BoundsError, match="gyro rate"), SessionWriter(tmp_path / "a", meta) as w:
        w.add_imu(np.array([0, 1000]), np.array([[0.0, 0, 0], [0, 0, 500.0]]))
    with (
        pytest.raises(BoundsError, match="line 2: exposure"),
        SessionWriter(tmp_path / "b", meta) as w,
    ):
        w.add_frame(0, img, 10**10)
        w.add_frame(33_333_333, img, 10**7)
    with (
        pytest.raises(BoundsError, match="line 3: exposure"),
        SessionWriter(tmp_path / "c", meta) as w,
    ):
        w.add_frame(0, img, 10**7)
        w.add_frame(33_333_333, img, 10**10)  # the last frame: checked on close
    with SessionWriter(tmp_path / "d", meta) as w:  # one frame has no interval
        w.add_frame(0, img, 10**10)
        w.add_imu(np.array([0, 1000]), np.zeros((2, 3)))
    assert len(load_session(tmp_path / "d").frames) == 1
    assert issubclass(BoundsError, SessionError)


@pytest.mark.skipif(not (REAL / "deepgyro-shield").is_dir(), reason="shared data absent")
def test_an_importer_refuses_an_absurd_gyro_rate(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    src = tmp_path / "dg"
    shutil.copytree(REAL / "deepgyro-shield", src)
    imu = src / "imu" / "imu.txt"
    lines = imu.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("4 "))
    f = lines[k].split()
    lines[k] = " ".join([f[0], f[1], "1e308", f[3], f[4]])
    imu.write_text("\n".join(lines) + "\n")
    before = tree_hashes(src)
    rc = main(["import", "deepgyro", str(src), str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "100 rad/s" in err, err
    assert not (tmp_path / "out").exists() and tree_hashes(src) == before
    assert debris(tmp_path) == []


def test_predict_refuses_when_the_gyro_covers_no_frame(
    env: Path, capsys: pytest.CaptureFixture
) -> None:
    imu = env / "S" / "imu0" / "data.csv"
    lines = imu.read_text().splitlines()
    imu.write_text("\n".join(lines[:3]) + "\n")  # the gyro ends before the first exposure
    out = env / "p"
    args = ["predict", str(env / "S"), "--calib", str(env / "calib.yaml"), "--out", str(out)]
    err = _refused([*args, "--skip-uncovered"], env, capsys, "covers none of the 3 frames")
    assert "nan" not in err and not out.exists()
