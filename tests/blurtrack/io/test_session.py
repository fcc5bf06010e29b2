"""Session folder round trip and one-line failures on malformed input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blurtrack.errors import ConfigError, SessionError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import read_calibration, write_calibration
from blurtrack.io.session import ImuConfig, SessionMeta, SessionWriter, load_session

META = SessionMeta(
    Camera((8, 6), (10.0, 10.0, 3.5, 2.5), readout_s=0.01),
    ImuConfig(rate_hz=200.0, timeshift_cam_imu=0.002),
)


def make_session(root: Path, n_frames: int = 3, accel: bool = True) -> Path:
    folder = root / "s"
    rng = np.random.default_rng(0)
    with SessionWriter(folder, META) as w:
        for i in range(n_frames):
            w.add_frame(
                1_000_000 + i * 33_000_000, rng.integers(0, 255, (6, 8), np.uint8), 20_000_000
            )
        t = np.arange(0, 200) * 5_000_000
        w.add_imu(t[:100], rng.normal(size=(100, 3)), rng.normal(size=(100, 3)) if accel else None)
        w.add_imu(t[100:], rng.normal(size=(100, 3)), rng.normal(size=(100, 3)) if accel else None)
        w.write_truth({"note": "simulated"})
    return folder


def test_round_trip(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    s = load_session(folder)
    assert s.meta.camera == META.camera and s.meta.target_kind == "laser-grid"
    np.testing.assert_allclose(s.meta.imu.T_cam_imu, np.eye(4))
    assert s.frames.timestamp_ns.tolist() == [1_000_000, 34_000_000, 67_000_000]
    assert s.imu_t_ns.size == 200 and s.accel_mps2 is not None
    assert s.read_image(1).shape == (6, 8)
    assert s.truth == {"note": "simulated"}
    np.testing.assert_allclose(s.exposures_s, 0.02)
    cal = s.initial_calibration()
    assert cal.timeshift_cam_imu_s == pytest.approx(0.002)
    assert s.gyro().rate_hz == pytest.approx(200.0)


def test_writer_refuses_non_empty_folder_and_bad_order(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    with pytest.raises(SessionError, match="non-empty"):
        SessionWriter(folder, META)
    with SessionWriter(tmp_path / "t", META) as w:
        w.add_frame(10, np.zeros((6, 8), np.uint8), 5)
        with pytest.raises(SessionError, match="not after"):
            w.add_frame(10, np.zeros((6, 8), np.uint8), 5)
    # The rejected frame left the already written one intact and loadable.
    assert len(load_session(tmp_path / "t").frames) == 1


def _edit(path: Path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new, 1))


@pytest.mark.parametrize(
    ("target", "old", "new", "message"),
    [
        ("imu0/data.csv", "\n5000000,", "\n5000000,nan,0,", "Expected 7 fields"),
        ("imu0/data.csv", "\n10000000,", "\n5000000,", "duplicate timestamp"),
        ("imu0/data.csv", "\n10000000,", "\n1,", "unsorted timestamp"),
        ("cam0/data.csv", "34000000.png", "../../etc/passwd", "plain name"),
        ("cam0/data.csv", ",20000000\n", ",x20\n", "not a finite number"),
        ("session.yaml", "blurtrack-session/1", "other/2", "format"),
        ("session.yaml", "readout_s: 0.01", "readout_s: -3", "readout_s"),
    ],
)
def test_malformed_sessions_give_one_line_errors(
    tmp_path: Path, target: str, old: str, new: str, message: str
) -> None:
    folder = make_session(tmp_path)
    _edit(folder / target, old, new)
    with pytest.raises(SessionError, match=message) as info:
        load_session(folder)
    assert "\n" not in str(info.value)


def test_nan_gyro_value_is_refused(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    fields = lines[4].split(",")
    fields[2] = "nan"
    lines[4] = ",".join(fields)
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(SessionError, match="line 5, column 3: 'nan' is not a finite number"):
        load_session(folder)


def test_missing_column_and_missing_image(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0]] + [",".join(x.split(",")[:3]) for x in lines[1:]]) + "\n")
    with pytest.raises(SessionError, match="columns"):
        load_session(folder)
    folder2 = make_session(tmp_path / "b")
    (folder2 / "cam0" / "data" / "34000000.png").unlink()
    with pytest.raises(SessionError, match="missing"):
        load_session(folder2)


def test_image_that_does_not_decode(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    (folder / "cam0" / "data" / "34000000.png").write_bytes(b"\x89PNG garbage")
    s = load_session(folder)
    with pytest.raises(SessionError, match="does not decode"):
        s.read_image(1)


def test_gyro_gap_inside_exposures_is_refused_when_asked(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:5] + lines[15:]) + "\n")  # drop 50 ms of samples
    load_session(folder)  # accepted by default (checked at use time)
    with pytest.raises(SessionError, match="gyro gap of 55.0 ms"):
        load_session(folder, max_gyro_gap_s=0.02)


def test_calibration_yaml_round_trip_and_errors(tmp_path: Path) -> None:
    cal = Calibration(
        Camera(
            (1280, 720),
            (900.0, 905.0, 640.2, 361.0),
            "radtan",
            (-0.1, 0.01, 0.0, 0.0),
            readout_s=0.021,
        ),
        R_cam_imu=np.array([[0, 1.0, 0], [1.0, 0, 0], [0, 0, -1.0]]),
        timeshift_cam_imu_s=-0.0123,
        gyro_bias_radps=np.array([1e-3, 0, -2e-3]),
        sigma={"timeshift_cam_imu": 1e-5},
    )
    write_calibration(cal, tmp_path / "c.yaml")
    back = read_calibration(tmp_path / "c.yaml")
    assert back.camera == cal.camera
    np.testing.assert_allclose(back.R_cam_imu, cal.R_cam_imu)
    assert back.timeshift_cam_imu_s == cal.timeshift_cam_imu_s
    assert back.sigma == {"timeshift_cam_imu": 1e-5}
    text = (tmp_path / "c.yaml").read_text()
    for key in ("cam0:", "camera_model: pinhole", "T_cam_imu:", "timeshift_cam_imu:"):
        assert key in text
    (tmp_path / "bad.yaml").write_text("cam0: {intrinsics: [1, 2]}\n")
    with pytest.raises(ConfigError, match="resolution"):
        read_calibration(tmp_path / "bad.yaml")
    bad_rot = text.replace("- [0.0, 1.0, 0.0, 0.0]", "- [0.0, 2.0, 0.0, 0.0]")
    (tmp_path / "rot.yaml").write_text(bad_rot)
    with pytest.raises(ConfigError, match="rotation"):
        read_calibration(tmp_path / "rot.yaml")
    (tmp_path / "evil.yaml").write_text("!!python/object/apply:os.system ['true']\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        read_calibration(tmp_path / "evil.yaml")


def test_validate_reports_undecodable_frames_and_uncovered_exposures(tmp_path: Path) -> None:
    from blurtrack.cli import main
    from blurtrack.io.validate import validate_session

    folder = make_session(tmp_path)
    rep = validate_session(folder)
    assert rep.ok and rep.frames_covered == 3
    (folder / "cam0" / "data" / "67000000.png").write_bytes(b"broken")
    rep = validate_session(folder)
    assert not rep.ok and "does not decode" in rep.errors[0]
    assert main(["validate", str(folder)]) == 1
    csv = folder / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:8]) + "\n")  # gyro ends after 30 ms
    rep = validate_session(folder)
    assert any("gyro covers" in w for w in rep.warnings)


def test_axes_known_defaults_true_and_is_validated(tmp_path: Path) -> None:
    base = {
        "format": "blurtrack-session/1",
        "camera": {"resolution": [4, 3], "intrinsics": [2.0, 2.0, 1.5, 1.0]},
    }
    assert SessionMeta.from_dict(base).imu.axes_known is True  # sessions written before the key
    meta = SessionMeta.from_dict({**base, "imu": {"axes_known": False}})
    assert meta.imu.axes_known is False and meta.to_dict()["imu"]["axes_known"] is False
    with pytest.raises(SessionError, match="axes_known must be true or false"):
        SessionMeta.from_dict({**base, "imu": {"axes_known": "no"}})
