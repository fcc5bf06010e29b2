"""EuRoC, ROS bag and video+gcsv importers, and the ROS bag export: round trips on small inputs
that the tests write themselves, and the one-line refusals of bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from blurtrack.cli import main
from blurtrack.errors import BlurTrackError, ImportFormatError
from blurtrack.io.importers import import_euroc, import_rosbag, import_video
from blurtrack.io.importers.video import read_gcsv
from blurtrack.io.session import load_session
from blurtrack.testing.mini_session import write_synthetic_session

W, H = 64, 48


def _frames(n: int = 5, colour: bool = False) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    shape = (H, W, 3) if colour else (H, W)
    return [rng.integers(0, 255, shape, dtype=np.uint8) for _ in range(n)]


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _write_euroc(root: Path, T_BS_cam: np.ndarray) -> list[np.ndarray]:
    cam, imu = root / "mav0" / "cam0", root / "mav0" / "imu0"
    (cam / "data").mkdir(parents=True)
    imu.mkdir(parents=True)
    imgs = _frames()
    rows = ["#timestamp [ns],filename"]
    for i, img in enumerate(imgs):
        ts = 1_000_000_000 + i * 50_000_000
        cv2.imwrite(str(cam / "data" / f"{ts}.png"), img)
        rows.append(f"{ts},{ts}.png")
    (cam / "data.csv").write_text("\n".join(rows) + "\n")
    data = ", ".join(repr(float(v)) for v in T_BS_cam.ravel())
    (cam / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{data}]\nrate_hz: 20\nresolution: [{W}, {H}]\ncamera_model: pinhole\n"
        "intrinsics: [58.6, 57.3, 31.2, 24.4] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        "distortion_coefficients: [-0.28, 0.07, 0.0002, 1.7e-05]\n"
    )
    (imu / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: imu\nT_BS:\n  cols: 4\n  rows: 4\n"
        "  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n"
        "rate_hz: 200\ngyroscope_noise_density: 1.6968e-04\n"
        "accelerometer_noise_density: 2.0e-3\n"
    )
    t = 990_000_000 + 5_000_000 * np.arange(60)
    lines = [
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
        "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
    ]
    lines += [f"{ti},{0.1 * k},-0.2,0.3,9.8,0.0,0.1" for k, ti in enumerate(t)]
    (imu / "data.csv").write_text("\n".join(lines) + "\n")
    return imgs


def test_euroc_round_trip_derives_T_cam_imu(tmp_path: Path) -> None:
    T_BS = np.eye(4)
    T_BS[:3, :3] = _rot_z(90.0)
    T_BS[:3, 3] = [0.02, -0.06, 0.01]
    imgs = _write_euroc(tmp_path / "e", T_BS)
    out = tmp_path / "s"
    assert main(["import", "euroc", str(tmp_path / "e"), str(out), "--exposure-ms", "8"]) == 0
    s = load_session(out)
    assert s.meta.imu.axes_known is True  # the recording states it
    np.testing.assert_allclose(s.meta.imu.T_cam_imu, np.linalg.inv(T_BS), atol=1e-12)
    assert s.meta.camera.distortion_model == "radtan"
    assert s.meta.camera.intrinsics == pytest.approx((58.6, 57.3, 31.2, 24.4))
    assert s.exposures_s == pytest.approx(0.008)
    assert s.frames.timestamp_ns.iloc[1] == 1_050_000_000
    assert np.array_equal(s.read_image(2), imgs[2])
    assert s.omega_radps[3] == pytest.approx([0.3, -0.2, 0.3])
    assert s.accel_mps2 is not None and s.accel_mps2[0] == pytest.approx([9.8, 0.0, 0.1])
    noise = s.meta.extra["import"]["imu_noise"]
    assert noise["gyroscope_noise_density"] == pytest.approx(1.6968e-4)


def test_euroc_bad_input_is_refused(tmp_path: Path) -> None:
    T_BS = np.diag([1.0, 1.0, -1.0, 1.0])  # a reflection
    _write_euroc(tmp_path / "e", T_BS)
    with pytest.raises(ImportFormatError, match="not a proper rigid transform"):
        import_euroc(tmp_path / "e", tmp_path / "a", exposure_s=0.01)
    _write_euroc(tmp_path / "f", np.eye(4))
    with pytest.raises(ImportFormatError, match="give --exposure-ms"):
        import_euroc(tmp_path / "f", tmp_path / "b")
    csv = tmp_path / "f" / "mav0" / "cam0" / "data.csv"
    csv.write_text("#timestamp [ns],filename\n1000,../../imu0/data.csv\n")
    with pytest.raises(ImportFormatError, match="plain name"):
        import_euroc(tmp_path / "f", tmp_path / "c", exposure_s=0.01)
    assert main(["import", "euroc", str(tmp_path / "f"), str(tmp_path / "d")]) == 2


@pytest.mark.parametrize("ros2", [False, True])
def test_rosbag_export_then_import_round_trip(tmp_path: Path, ros2: bool) -> None:
    write_synthetic_session(tmp_path / "s", n_frames=3, resolution=(96, 64))
    s = load_session(tmp_path / "s")
    bag = tmp_path / ("b" if ros2 else "b.bag")
    argv = ["export", "rosbag", str(tmp_path / "s"), str(bag)] + (["--ros2"] if ros2 else [])
    assert main(argv) == 0

    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:  # the rosbags reader sees what Kalibr needs
        topics = {t: i.msgtype for t, i in reader.topics.items()}
        assert topics["/cam0/image_raw"] == "sensor_msgs/msg/Image"
        assert topics["/imu0"] == "sensor_msgs/msg/Imu"
        conn = [c for c in reader.connections if c.topic == "/cam0/image_raw"]
        msgs = [reader.deserialize(r, c.msgtype) for c, _, r in reader.messages(conn)]
        assert [m.encoding for m in msgs] == ["mono8"] * 3
        st = msgs[1].header.stamp
        assert st.sec * 10**9 + st.nanosec == s.frames.timestamp_ns.iloc[1]
    if ros2:  # a second, independent reader: the mcap library sees ROS 2 message definitions
        from mcap.reader import make_reader

        (mcap_file,) = bag.glob("*.mcap")
        with mcap_file.open("rb") as f:
            summary = make_reader(f).get_summary()
        names = {sc.name: sc.encoding for sc in summary.schemas.values()}
        assert names["sensor_msgs/msg/Image"] == "ros2msg"
        counts = summary.statistics.channel_message_counts
        by_topic = {summary.channels[c].topic: k for c, k in counts.items()}
        assert by_topic == {"/cam0/image_raw": 3, "/cam0/camera_info": 3, "/imu0": s.imu_t_ns.size}

    from blurtrack.geometry.calibration import Calibration
    from blurtrack.io.calibration import read_calibration, write_calibration

    cams = read_calibration(tmp_path / "b.camchain.yaml")  # Kalibr --cams beside the bag
    assert cams.camera == s.meta.camera
    imu_yaml = (tmp_path / "b.imu.yaml").read_text()
    assert "rostopic: /imu0" in imu_yaml and "update_rate: 1000.0" in imu_yaml
    assert main(argv) == 2  # never overwrites
    out = tmp_path / "back"
    exp_ms = str(1e3 * s.exposures_s[0])
    assert main(["import", "rosbag", str(bag), str(out), "--exposure-ms", exp_ms]) == 0
    r = load_session(out)
    assert r.frames.timestamp_ns.tolist() == s.frames.timestamp_ns.tolist()
    assert all(np.array_equal(r.read_image(i), s.read_image(i)) for i in range(3))
    np.testing.assert_array_equal(r.imu_t_ns, s.imu_t_ns)
    np.testing.assert_array_equal(r.omega_radps, s.omega_radps)
    assert r.accel_mps2 is None  # covariance[0] = -1 read back as "no accelerometer"
    assert r.meta.camera.intrinsics == pytest.approx(s.meta.camera.intrinsics)  # CameraInfo
    assert r.meta.imu.axes_known is False  # a bag does not state the axes
    # --calib with a Kalibr camchain that states T_cam_imu: the axes are known
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    write_calibration(Calibration(s.meta.camera, R_cam_imu=R), tmp_path / "k.yaml")
    argv = ["import", "rosbag", str(bag), str(tmp_path / "k"), "--exposure-ms", exp_ms]
    assert main([*argv, "--calib", str(tmp_path / "k.yaml")]) == 0
    k = load_session(tmp_path / "k")
    assert k.meta.imu.axes_known is True
    np.testing.assert_allclose(k.meta.imu.T_cam_imu[:3, :3], R)


def test_rosbag_colour_compressed_topic_choice_and_middle_stamps(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    bag = tmp_path / "c.bag"
    imgs = _frames(3, colour=True)

    def header(t_ns: int):
        stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="c")

    with Writer(bag) as w:
        c_png = w.add_connection("/cam/png", "sensor_msgs/msg/CompressedImage", typestore=ts)
        c_raw = w.add_connection("/cam/raw", "sensor_msgs/msg/Image", typestore=ts)
        c_imu = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        for i, img in enumerate(imgs):
            t = 10**9 + i * 40_000_000
            png = np.frombuffer(cv2.imencode(".png", img)[1].tobytes(), np.uint8)
            msg = T["sensor_msgs/msg/CompressedImage"](header=header(t), format="png", data=png)
            w.write(c_png, t, ts.serialize_ros1(msg, msg.__msgtype__))
            rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
            raw = T["sensor_msgs/msg/Image"](
                header=header(t), height=H, width=W, encoding="rgb8", is_bigendian=0,
                step=3 * W, data=rgb.reshape(-1),
            )  # fmt: skip
            w.write(c_raw, t, ts.serialize_ros1(raw, raw.__msgtype__))
        V = T["geometry_msgs/msg/Vector3"]
        for k in range(40):
            t = 990_000_000 + k * 5_000_000
            msg = T["sensor_msgs/msg/Imu"](
                header=header(t),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1),
                orientation_covariance=np.r_[-1.0, np.zeros(8)],
                angular_velocity=V(x=0.01 * k, y=0.0, z=-1.0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=V(x=0.0, y=9.81, z=0.0),
                linear_acceleration_covariance=np.zeros(9),
            )
            w.write(c_imu, t, ts.serialize_ros1(msg, msg.__msgtype__))
    with pytest.raises(ImportFormatError, match=r"2 image topics.*/cam/png.*/cam/raw.*/imu"):
        import_rosbag(bag, tmp_path / "x", exposure_s=0.01)
    with pytest.raises(ImportFormatError, match="no image topic '/nope'; the bag has"):
        import_rosbag(bag, tmp_path / "y", exposure_s=0.01, image_topic="/nope")
    for topic in ("/cam/png", "/cam/raw"):
        out = tmp_path / topic.replace("/", "_")
        import_rosbag(bag, out, exposure_s=0.01, readout_s=0.004, stamp="middle", image_topic=topic)
        s = load_session(out)
        assert all(np.array_equal(s.read_image(i), imgs[i]) for i in range(3))
        assert s.frames.timestamp_ns.iloc[0] == 10**9 - 7_000_000  # (exposure + readout) / 2
        assert s.accel_mps2 is not None and s.omega_radps[2] == pytest.approx([0.02, 0, -1])
        assert s.meta.camera.intrinsics[0] == W  # stated guess: no CameraInfo, no --calib
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    with pytest.raises(ImportFormatError, match="not a readable bag"):
        import_rosbag(tmp_path / "junk.bag", tmp_path / "z", exposure_s=0.01)


def _write_video(path: Path, n: int, fps: float) -> None:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (W, H))
    assert vw.isOpened()
    for img in _frames(n, colour=True):
        vw.write(img)
    vw.release()


def _write_gcsv(path: Path, readout_ms: float = 12.5) -> None:
    rows = [f"{k},{100 + k},-200,300,0,2048,0" for k in range(0, 400)]
    path.write_text(
        "GYROFLOW IMU LOG\nversion,1.3\nid,test\norientation,YxZ\n"
        f"frame_readout_time,{readout_ms}\nframe_readout_direction,0\n"
        "tscale,0.001\ngscale,0.001\nascale,0.00048828125\nt,gx,gy,gz,ax,ay,az\n"
        + "\n".join(rows)
        + "\n"
    )


def test_video_with_gcsv_round_trip(tmp_path: Path) -> None:
    _write_video(tmp_path / "clip.avi", 6, 25.0)
    _write_gcsv(tmp_path / "clip.gcsv")
    out = tmp_path / "v"
    assert (
        main(["import", "video", str(tmp_path / "clip.avi"), str(out), "--exposure-ms", "5"]) == 0
    )
    s = load_session(out)
    assert len(s.frames) == 6 and s.meta.camera.resolution == (W, H)
    np.testing.assert_allclose(s.frame_times_s, np.arange(6) / 25.0, atol=1e-6)  # container
    assert s.meta.camera.readout_s == pytest.approx(0.0125)
    assert s.imu_t_ns[:3].tolist() == [0, 1_000_000, 2_000_000]
    assert s.omega_radps[1] == pytest.approx([0.101, -0.2, 0.3])
    assert s.accel_mps2[0] == pytest.approx([0.0, 9.80665, 0.0])
    assert s.meta.imu.axes_known is False


def test_video_and_cli_refusals(tmp_path: Path) -> None:
    _write_video(tmp_path / "clip.avi", 2, 25.0)
    with pytest.raises(ImportFormatError, match="missing file"):
        import_video(tmp_path / "clip.avi", tmp_path / "a", exposure_s=0.01)
    (tmp_path / "clip.gcsv").write_text("GYROFLOW IMU LOG\ntscale,1e9\nt,gx,gy,gz\n0,1,2,3\n")
    with pytest.raises(ImportFormatError, match="tscale"):
        read_gcsv(tmp_path / "clip.gcsv")
    (tmp_path / "bad.avi").write_bytes(b"not a video")
    _write_gcsv(tmp_path / "bad.gcsv")
    with pytest.raises(BlurTrackError, match="video"):
        import_video(tmp_path / "bad.avi", tmp_path / "b", exposure_s=0.01)
    argv = ["import", "deepgyro", str(tmp_path), str(tmp_path / "c"), "--image-topic", "/x"]
    assert main(argv) == 2
    argv = ["import", "video", str(tmp_path / "clip.avi"), str(tmp_path / "d")]
    assert main([*argv, "--exposure-ms", "-1"]) == 2


def test_ros_image_payloads_are_range_checked() -> None:
    from blurtrack.io.rosimage import decode_raw, encode_raw

    img16 = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    big = img16.astype(">u2").tobytes()
    np.testing.assert_array_equal(
        decode_raw(4, 3, "mono16", 1, 8, np.frombuffer(big, np.uint8)), img16
    )
    enc, step, data = encode_raw(img16)
    assert (enc, step) == ("mono16", 8)
    np.testing.assert_array_equal(
        decode_raw(4, 3, enc, 0, step, np.frombuffer(data, np.uint8)), img16
    )
    padded = np.zeros(3 * 10, np.uint8)  # step 10 > 4 bytes per row: padding is dropped
    padded.reshape(3, 10)[:, :4] = 7
    assert (decode_raw(4, 3, "mono8", 0, 10, padded) == 7).all()
    with pytest.raises(ImportFormatError, match="do not fit"):
        decode_raw(4, 3, "mono8", 0, 4, np.zeros(5, np.uint8))
    with pytest.raises(ImportFormatError, match="outside"):
        decode_raw(100_000, 3, "mono8", 0, 100_000, np.zeros(10, np.uint8))
    with pytest.raises(ImportFormatError, match="not supported"):
        decode_raw(4, 3, "bayer_rggb8", 0, 4, np.zeros(12, np.uint8))
