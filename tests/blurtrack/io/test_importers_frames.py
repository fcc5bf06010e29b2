"""``blurtrack import frames``: a folder of frames, a frame-times file, a gyro CSV."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.errors import ImportFormatError
from blurtrack.io.importers import import_frames
from blurtrack.io.session import load_session

T0_S = 4328040.426246  # a phone's boot-clock seconds: float seconds lose ns, Decimal does not
FPS = 30.0


def _layout(
    root: Path,
    n_frames: int = 6,
    first_number: int = 1,
    extra_lines: int = 0,
    gyro_header: str | None = "t,gx,gy,gz",
    gyro_time_scale: float = 1e3,  # ms
    gyro_scale: float = 1.0,
    time_last: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lab layout under ``root``; returns (frame times s, gyro times s, gyro rad/s)."""
    (root / "imgs").mkdir(parents=True)
    n_lines = first_number - 1 + n_frames + extra_lines
    t_frames = T0_S + np.arange(n_lines) / FPS
    lines = [f"{t:.6f}" for t in t_frames]
    (root / "frame_times.txt").write_text("\n".join(lines) + "\n")
    for k in range(first_number, first_number + n_frames):
        img = np.full((24, 32), 10 * k, np.uint8)
        cv2.imwrite(str(root / "imgs" / f"cam-{k}.png"), img)
    t_g = T0_S - 0.1 + np.arange(int((n_lines / FPS + 0.2) * 400)) / 400.0
    rng = np.random.default_rng(0)
    w = rng.normal(0, 0.3, (t_g.size, 3))
    rows = []
    for t, (x, y, z) in zip(t_g, (w * gyro_scale).tolist(), strict=True):
        ts = f"{t * gyro_time_scale:.6f}"
        rows.append(f"{x!r},{y!r},{z!r},{ts}" if time_last else f"{ts},{x!r},{y!r},{z!r}")
    head = [] if gyro_header is None else [gyro_header]
    (root / "gyro.csv").write_text("\n".join(head + rows) + "\n")
    return t_frames, t_g, w


def test_layout_imports_with_units_columns_and_numbers_detected(tmp_path: Path) -> None:
    src = tmp_path / "src"
    t_frames, t_g, w = _layout(src, n_frames=6, first_number=3, extra_lines=4)
    summary = import_frames(src, tmp_path / "out", exposure_s=0.005)
    s = load_session(tmp_path / "out")
    assert summary["frames"] == 6 and summary["frames_covered_by_gyro"] == 6
    # frame k (from the name cam-k.png) takes line k; times exact to the ns via Decimal
    expect = [round(float(f"{t:.6f}") * 1e6) * 1000 for t in t_frames[2:8]]
    assert s.frames["timestamp_ns"].tolist() == expect
    means = [float(s.read_image(i).mean()) for i in range(6)]
    assert means == [10.0 * k for k in range(3, 9)]
    assert "unit s (detected)" in summary["assumptions"]["frame_times"]
    assert summary["assumptions"]["gyro_time_unit"] == "ms (detected)"
    assert "header" in summary["assumptions"]["gyro_columns"]
    np.testing.assert_allclose(s.omega_radps, w, atol=1e-12)
    np.testing.assert_allclose(s.imu_times_s, t_g, atol=1e-6)
    assert s.meta.imu.axes_known is False
    assert s.meta.target_kind == "natural"


def test_headerless_gyro_time_last_and_degrees(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _, _, w = _layout(
        src, gyro_header=None, gyro_time_scale=1.0, gyro_scale=180 / np.pi * 20, time_last=True
    )
    summary = import_frames(src, tmp_path / "out", exposure_s=0.005)
    s = load_session(tmp_path / "out")
    assert summary["assumptions"]["gyro_columns"].startswith("time = the increasing column 4")
    assert summary["assumptions"]["gyro_unit"].startswith("deg/s")
    np.testing.assert_allclose(s.omega_radps, w * 20, rtol=1e-9)


def test_given_columns_and_units_override_detection(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _, _, w = _layout(src, gyro_header=None, gyro_time_scale=1.0, time_last=True)
    import_frames(
        src,
        tmp_path / "out",
        exposure_s=0.005,
        gyro_columns="wy,wx,wz,t",
        time_unit="s",
        gyro_unit="rad/s",
    )
    s = load_session(tmp_path / "out")
    np.testing.assert_allclose(s.omega_radps, w[:, [1, 0, 2]], atol=1e-12)


def test_time_filename_rows(tmp_path: Path) -> None:
    src = tmp_path / "src"
    t_frames, _, _ = _layout(src, n_frames=4)
    names = [f"cam-{k}.png" for k in (1, 2, 3, 4)]
    rows = [f"{round(t * 1e9)},{n}" for t, n in zip(t_frames[:4], names, strict=True)]
    (src / "frame_times.txt").write_text("\n".join(rows[::-1]) + "\n")  # any order
    summary = import_frames(src, tmp_path / "out", exposure_s=0.005)
    s = load_session(tmp_path / "out")
    assert summary["assumptions"]["frame_times"].startswith("frame_times.txt, unit ns")
    np.testing.assert_array_equal(s.frames["timestamp_ns"], [round(t * 1e9) for t in t_frames[:4]])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("other_clock", "covers none of the frames"),
        ("two_gyro_files", "gyro file not found unambiguously"),
        ("frame_beyond_lines", "frame number outside"),
        ("decreasing", "do not increase"),
        ("bad_number", "is not a number"),
        ("no_exposure", "--exposure-ms"),
        ("wrong_unit", "with --time-unit ms the median step is 3.333"),
    ],
)
def test_bad_layouts_are_refused_with_the_reason(tmp_path: Path, change: str, message: str) -> None:
    src = tmp_path / "src"
    t_frames, _, _ = _layout(src)
    kwargs: dict = {"exposure_s": 0.005}
    if change == "other_clock":  # a gyro log of another recording: an hour later
        text = (src / "gyro.csv").read_text().splitlines()
        shifted = [text[0]] + [
            f"{float(r.split(',')[0]) + 3.6e6:.6f}," + r.split(",", 1)[1] for r in text[1:]
        ]
        (src / "gyro.csv").write_text("\n".join(shifted) + "\n")
    elif change == "two_gyro_files":
        (src / "imu_copy.csv").write_text((src / "gyro.csv").read_text())
    elif change == "frame_beyond_lines":
        cv2.imwrite(str(src / "imgs" / "cam-99.png"), np.zeros((24, 32), np.uint8))
    elif change == "decreasing":
        (src / "frame_times.txt").write_text("\n".join(f"{t:.6f}" for t in t_frames[::-1]) + "\n")
    elif change == "bad_number":
        (src / "frame_times.txt").write_text("0.1\n0.2x\n")
    elif change == "no_exposure":
        kwargs = {}
    elif change == "wrong_unit":  # the frame times are seconds
        kwargs["time_unit"] = "ms"
    with pytest.raises(ImportFormatError, match=message):
        import_frames(src, tmp_path / "out", **kwargs)
    assert not (tmp_path / "out" / "session.yaml").exists()


def test_cli_refuses_in_one_line_and_leaves_no_session(tmp_path: Path, capsys) -> None:
    src = tmp_path / "src"
    _layout(src)
    # frames at 1..6 s, the gyro at 4.3e6 s: not one clock
    (src / "frame_times.txt").write_text("1\n2\n3\n4\n5\n6\n")
    rc = main(["import", "frames", str(src), str(tmp_path / "out"), "--exposure-ms", "5"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "covers none of the frames" in err
    assert not (tmp_path / "out").exists()


def test_options_of_other_importers_are_refused(tmp_path: Path, capsys) -> None:
    src = tmp_path / "src"
    _layout(src)
    rc = main(["import", "frames", str(src), str(tmp_path / "o"), "--gcsv", "x.gcsv"])
    assert rc == 2 and "does not take --gcsv" in capsys.readouterr().err


def test_phone_video_imports_in_one_command(shared_data: Path, tmp_path: Path, capsys) -> None:
    src = shared_data / "real" / "phone-video-412hz"
    out = tmp_path / "phone"
    argv = ["import", "frames", str(src), str(out), "--exposure-ms", "5.1"]
    assert main([*argv, "--intrinsics", "573.85,575.04,406.01,309.01"]) == 0
    printed = capsys.readouterr().out
    assert "line k = the image whose name ends in k" in printed
    s = load_session(out)
    assert len(s.frames) == 52 and s.omega_radps.shape == (1524, 3)
    lines = (src / "framestamp.txt").read_text().split()
    expect = [int(lines[k - 1].replace(".", "")) for k in range(100, 152)]  # 9 decimals: ns
    assert s.frames["timestamp_ns"].tolist() == expect
    assert s.meta.camera.resolution == (800, 600)


def test_turn_180_stores_the_frames_and_the_camera_turned(tmp_path: Path, capsys) -> None:
    src = tmp_path / "src"
    _layout(src)
    # A mark in each frame's top-left corner: after turning it lies bottom right.
    for k in range(1, 7):
        img = np.full((24, 32), 10 * k, np.uint8)
        img[2, 3] = 250
        cv2.imwrite(str(src / "imgs" / f"cam-{k}.png"), img)
    k_opt = ["--intrinsics", "30,31,15,11"]
    base = ["import", "frames", str(src)]
    assert main([*base, str(tmp_path / "up"), "--exposure-ms", "5", *k_opt]) == 0
    assert main([*base, str(tmp_path / "t"), "--exposure-ms", "5", "--turn-180", *k_opt]) == 0
    assert "turned: 6 frames by 180 degrees" in capsys.readouterr().out
    up, turned = load_session(tmp_path / "up"), load_session(tmp_path / "t")
    for i in range(6):
        np.testing.assert_array_equal(turned.read_image(i), up.read_image(i)[::-1, ::-1])
    assert turned.read_image(0)[24 - 1 - 2, 32 - 1 - 3] == 250
    assert turned.meta.camera.intrinsics == (30.0, 31.0, 32 - 1 - 15.0, 24 - 1 - 11.0)
    T_up, T_turned = up.meta.imu.T_cam_imu, turned.meta.imu.T_cam_imu
    np.testing.assert_allclose(T_turned, np.diag([-1.0, -1.0, 1.0, 1.0]) @ T_up)
    np.testing.assert_array_equal(turned.frame_times_s, up.frame_times_s)
    np.testing.assert_array_equal(turned.omega_radps, up.omega_radps)
