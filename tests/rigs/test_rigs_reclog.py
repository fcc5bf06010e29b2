"""Recorder log: round trips, truncation at any byte, recover, and refusal of foreign files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigs.camera_types import CameraFrame
from rigs.errors import RecorderLogError
from rigs.reclog import RecLogWriter, iter_frames, scan_log
from rigs.recover import recover_log


def _write(path: Path, n_chunks: int = 6) -> tuple[list[np.ndarray], np.ndarray]:
    rng = np.random.default_rng(0)
    w = RecLogWriter(path, {"imu_url": "sim://imu"})
    images, gyro = [], rng.normal(size=(n_chunks * 10, 3))
    for c in range(n_chunks):
        sl = slice(10 * c, 10 * c + 10)
        idx = np.arange(sl.start, sl.stop)
        w.write_imu(c, idx, idx * 1000, idx * 1000 + 5, gyro[sl], None)
        img = (
            rng.integers(0, 65535, (6, 5, 3), dtype=np.uint16)
            if c % 2
            else rng.integers(0, 255, (6, 5), dtype=np.uint8)
        )
        images.append(img)
        w.write_frame(CameraFrame(c, img, 100 * c, 7, c, "driver"), img.tobytes())
        w.flush()  # one chunk per iteration
    w.finish()
    return images, gyro


def test_round_trip_raw_frames_and_imu(tmp_path: Path) -> None:
    images, gyro = _write(tmp_path / "a.mcap")
    scan = scan_log(tmp_path / "a.mcap")
    assert scan.complete and scan.damage == "" and scan.metadata["imu_url"] == "sim://imu"
    np.testing.assert_array_equal(scan.gyro_radps, gyro)  # JSON keeps floats exact
    np.testing.assert_array_equal(scan.imu_index, np.arange(60))
    frames = list(iter_frames(tmp_path / "a.mcap"))
    for rec, img in zip(frames, images, strict=True):
        out = rec.image()
        assert out.dtype == img.dtype
        np.testing.assert_array_equal(out, img)


def test_truncation_at_any_byte_gives_a_prefix(tmp_path: Path) -> None:
    _, gyro = _write(tmp_path / "a.mcap")
    data = (tmp_path / "a.mcap").read_bytes()
    cut_path = tmp_path / "cut.mcap"
    sizes = []
    meta_end = data.index(b"sim://imu") + len("sim://imu")  # end of the metadata record
    cut_path.write_bytes(data[: meta_end - 1])
    with pytest.raises(RecorderLogError, match="not a BlurTrack recorder log"):
        scan_log(cut_path)
    for cut in range(meta_end, len(data), 97):
        cut_path.write_bytes(data[:cut])
        scan = scan_log(cut_path)
        assert not scan.complete and "near byte" in scan.damage
        n = scan.imu_index.size
        np.testing.assert_array_equal(scan.imu_index, np.arange(n))
        np.testing.assert_array_equal(scan.gyro_radps, gyro[:n])
        assert len(list(iter_frames(cut_path))) == scan.frame_timestamps_ns.size
        sizes.append(n)
    assert sizes == sorted(sizes) and sizes[-1] == 60  # monotone, all chunks before the index


def test_recover_writes_a_complete_log(tmp_path: Path) -> None:
    _write(tmp_path / "a.mcap")
    data = (tmp_path / "a.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    res = recover_log(tmp_path / "cut.mcap", tmp_path / "fixed.mcap")
    fixed = scan_log(tmp_path / "fixed.mcap")
    assert not res.was_complete and fixed.complete
    assert fixed.imu_index.size == res.imu_samples > 0
    assert "recovered from cut.mcap" in fixed.events[-1]["message"]
    with pytest.raises(RecorderLogError, match="already exists"):
        recover_log(tmp_path / "cut.mcap", tmp_path / "fixed.mcap")
    with pytest.raises(RecorderLogError, match="must not overwrite"):
        recover_log(tmp_path / "cut.mcap", tmp_path / "cut.mcap")


def test_foreign_and_damaged_files_are_refused(tmp_path: Path) -> None:
    (tmp_path / "text.mcap").write_text("hello")
    with pytest.raises(RecorderLogError, match="not a BlurTrack recorder log"):
        scan_log(tmp_path / "text.mcap")
    from mcap.writer import Writer

    with open(tmp_path / "other.mcap", "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("recording", {"format": "someone-else/9"})
        w.finish()
    with pytest.raises(RecorderLogError, match="unsupported log format"):
        scan_log(tmp_path / "other.mcap")


def test_raw_frame_with_inconsistent_size_is_refused(tmp_path: Path) -> None:
    w = RecLogWriter(tmp_path / "b.mcap", {})
    img = np.zeros((4, 4), np.uint8)
    w.write_frame(CameraFrame(0, img, 1, 1, 1, "host"), img.tobytes()[:-1])
    w.finish()
    (rec,) = iter_frames(tmp_path / "b.mcap")
    with pytest.raises(RecorderLogError, match="do not make a 4x4x1 image"):
        rec.image()


def test_every_channel_decodes_with_the_mcap_reader_and_validates(tmp_path: Path) -> None:
    """What Foxglove needs: registered JSON schemas with declared properties, Foxglove's image
    and log schemas, one IMU message per sample at device time, images that decode."""
    import base64
    import json

    import cv2
    import jsonschema
    from mcap.reader import make_reader

    images, gyro = _write(tmp_path / "a.mcap")
    w = RecLogWriter(tmp_path / "p.mcap", {})
    png_img = np.arange(30, dtype=np.uint8).reshape(6, 5)
    png = cv2.imencode(".png", png_img)[1].tobytes()
    w.write_frame(CameraFrame(0, png_img, 10, 7, 11, "host"), png, "png")
    w.write_event(12, "error", "boom")
    w.finish()
    seen: dict[str, int] = {}
    for log, expected_images in (("a.mcap", images), ("p.mcap", [png_img])):
        decoded = []
        with open(tmp_path / log, "rb") as f:
            for schema, channel, msg in make_reader(f).iter_messages():
                assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                js = json.loads(schema.data)
                assert js["title"] == schema.name and js["properties"]  # declared, not empty
                obj = json.loads(msg.data)
                jsonschema.validate(obj, js)
                seen[schema.name] = seen.get(schema.name, 0) + 1
                if schema.name == "blurtrack.ImuSample":
                    assert msg.publish_time == obj["t_dev_us"] * 1000  # device time
                    t = obj["timestamp"]
                    assert t["sec"] * 10**9 + t["nsec"] == obj["t_dev_us"] * 1000
                    assert msg.log_time == obj["host_ns"]
                    np.testing.assert_array_equal(
                        [obj["gyro_radps"][k] for k in "xyz"], gyro[obj["index"]]
                    )
                elif schema.name == "foxglove.RawImage":
                    raw = base64.b64decode(obj["data"])
                    assert obj["encoding"] in ("mono8", "bgr8", "mono16")
                    assert obj["step"] * obj["height"] == len(raw)
                    dtype = np.dtype("<u2") if obj["encoding"] == "mono16" else np.uint8
                    decoded.append(
                        np.frombuffer(raw, dtype).reshape(obj["height"], obj["width"], -1)
                    )
                elif schema.name == "foxglove.CompressedImage":
                    assert obj["format"] == "png"
                    buf = np.frombuffer(base64.b64decode(obj["data"]), np.uint8)
                    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
                    decoded.append(img if img.ndim == 3 else img[..., None])
        for got, img in zip(decoded, expected_images, strict=True):
            np.testing.assert_array_equal(got, img if img.ndim == 3 else img[..., None])
    # 16-bit colour has no Foxglove raw encoding: those frames went in as lossless PNG
    assert seen["blurtrack.ImuSample"] == 60  # one message per sample
    assert seen["foxglove.RawImage"] == 3 and seen["foxglove.CompressedImage"] == 4
    assert seen["blurtrack.FrameInfo"] == 7 and seen["foxglove.Log"] == 1
    frames = list(iter_frames(tmp_path / "a.mcap"))
    for rec, img in zip(frames, images, strict=True):
        np.testing.assert_array_equal(rec.image(), img)  # PNG fallback is lossless
    assert scan_log(tmp_path / "p.mcap").events == [{"level": "error", "message": "boom"}]
