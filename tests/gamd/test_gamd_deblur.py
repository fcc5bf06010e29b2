"""`gamd deblur` on a recorded session with heat maps in `blurtrack predict`'s layout."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from blurtrack.geometry.camera import Camera
from blurtrack.io.session import SessionMeta, SessionWriter
from gamd.cli import main
from gamd.data import DeblurDataset
from gamd.infer import frame_to_rgb


@pytest.fixture(scope="module")
def checkpoint(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("gamd_ckpt")
    cfg = {
        "model": {"name": "gamd", "preset": "tiny"},
        "data": {"root": str(tiny_dataset), "crop": 16, "heat_scale_px": 8.0},
        "train": {
            "out_dir": str(out),
            "steps": 1,
            "batch_size": 1,
            "progress": False,
            "tensorboard": False,
        },
    }
    (out / "cfg.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["train", "--config", str(out / "cfg.yaml")]) == 0
    return out / "checkpoints/last.pt"


def _session(tmp_path, gray: bool):
    folder = tmp_path / "session"
    meta = SessionMeta(Camera((30, 22), (30.0, 30.0, 15.0, 11.0)), target_kind="natural")
    rng = np.random.default_rng(0)
    stamps = [1_000_000, 34_000_000]
    with SessionWriter(folder, meta) as w:
        for ts in stamps:
            img = rng.integers(0, 255, (22, 30) if gray else (22, 30, 3), dtype=np.uint8)
            w.add_frame(ts, img, 10_000_000)
        w.add_imu(np.array([0, 50_000_000]), np.zeros((2, 3)))
    pred = tmp_path / "pred"
    (pred / "heat").mkdir(parents=True)
    for ts in stamps:
        np.save(pred / "heat" / f"{ts}.npy", rng.normal(0, 3, (6, 22, 30)).astype(np.float32))
    return folder, pred, stamps


@pytest.mark.parametrize("gray", [False, True])
def test_deblur_session_writes_frames(checkpoint, tmp_path, gray, capsys) -> None:
    session, pred, stamps = _session(tmp_path, gray)
    out = tmp_path / "out"
    assert (
        main(
            [
                "deblur",
                str(session),
                "--checkpoint",
                str(checkpoint),
                "--heat",
                str(pred),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "2 frames" in capsys.readouterr().out
    for ts in stamps:
        img = cv2.imread(str(out / f"{ts}.png"))
        assert img.shape == (22, 30, 3)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == stamps and summary["heat_scale_px"] == 8.0


def test_deblur_refuses_missing_heat(checkpoint, tmp_path, capsys) -> None:
    session, pred, stamps = _session(tmp_path, False)
    (pred / "heat" / f"{stamps[1]}.npy").unlink()
    assert (
        main(
            [
                "deblur",
                str(session),
                "--checkpoint",
                str(checkpoint),
                "--heat",
                str(pred),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert f"no heat map for frame {stamps[1]}" in capsys.readouterr().err
    assert (
        main(
            ["deblur", str(session), "--checkpoint", str(checkpoint), "--out", str(tmp_path / "o2")]
        )
        == 2
    )
    assert "needs heat maps" in capsys.readouterr().err
    assert (
        main(
            [
                "deblur",
                str(session),
                "--checkpoint",
                str(checkpoint),
                "--heat",
                str(pred),
                "--out",
                str(tmp_path / "o3"),
                "--skip-missing",
            ]
        )
        == 0
    )
    assert "1 skipped" in capsys.readouterr().out
    summary = json.loads((tmp_path / "o3/summary.json").read_text())
    assert summary["frames"] == stamps[:1] and summary["skipped"] == stamps[1:]


def test_frame_to_rgb_conventions() -> None:
    bgr = np.zeros((2, 2, 3), np.uint16)
    bgr[..., 0] = 65535  # blue
    rgb = frame_to_rgb(bgr)
    assert rgb[0, 0].tolist() == [0.0, 0.0, 1.0]
    assert frame_to_rgb(np.full((2, 2), 255, np.uint8)).shape == (2, 2, 3)


def test_deblur_ensemble_option_reaches_the_restoration(checkpoint, tmp_path) -> None:
    """``--ensemble`` overrides the weights' own setting (1 here): the summary records it and
    the frames differ from the plain ones (the 1-step network is not flip-equivariant)."""
    session, pred, stamps = _session(tmp_path, False)
    base = ["deblur", str(session), "--checkpoint", str(checkpoint), "--heat", str(pred)]
    assert main([*base, "--out", str(tmp_path / "plain")]) == 0
    assert main([*base, "--out", str(tmp_path / "ens"), "--ensemble", "4"]) == 0
    plain = json.loads((tmp_path / "plain/summary.json").read_text())
    ens = json.loads((tmp_path / "ens/summary.json").read_text())
    assert plain["ensemble"] == 1 and ens["ensemble"] == 4
    a = cv2.imread(str(tmp_path / "plain" / f"{stamps[0]}.png")).astype(int)
    b = cv2.imread(str(tmp_path / "ens" / f"{stamps[0]}.png")).astype(int)
    assert np.abs(a - b).max() > 0


def test_export_sets_the_inference_ensemble_and_refuses_a_bad_one(checkpoint, tmp_path) -> None:
    from gamd.checkpoint import export_weights, load_model
    from gamd.errors import GamdConfigError

    out = export_weights(checkpoint, tmp_path / "w.pt", {"ensemble": 4})
    _, cfg, _ = load_model(out)
    assert cfg.data.restore_options().ensemble == 4
    _, plain, _ = load_model(export_weights(checkpoint, tmp_path / "p.pt"))
    assert plain.data.ensemble == 1 and plain.data.heat_scale_px == cfg.data.heat_scale_px
    with pytest.raises(GamdConfigError, match="ensemble"):
        export_weights(checkpoint, tmp_path / "bad.pt", {"ensemble": 3})
    assert not (tmp_path / "bad.pt").exists()


def test_demo_writes_before_after_picture(tiny_dataset, tmp_path) -> None:
    from blurtrack.cli.demo import demo_train

    s = demo_train(tiny_dataset, tmp_path / "demo", steps=3, crop=16, batch_size=2, progress=False)
    img = cv2.imread(s["picture"])
    assert img.shape[1] >= 3 * 480 and img.shape[0] > 400  # three labelled, magnified panels
    assert json.loads((tmp_path / "demo/summary.json").read_text())["steps"] == 3
    assert np.isfinite(s["restored_psnr_db"]) and s["image"].startswith("test/")
    json.dumps(s)  # the demo prints it


def test_demo_deblurs_with_the_shipped_weights(tiny_dataset, tmp_path) -> None:
    from blurtrack.cli.demo import demo_deblur
    from gamd.weights import shipped_weights

    s = demo_deblur(tiny_dataset, tmp_path / "demo")
    assert cv2.imread(s["picture"]).shape[1] >= 3 * 480  # three labelled, magnified panels
    assert s["checkpoint"] == str(shipped_weights("gamd")) and s["steps"] == 0
    assert json.loads((tmp_path / "demo/summary.json").read_text()) == s


def test_shipped_weights_improve_a_rolling_shutter_demo_image(tmp_path, shared_data) -> None:
    """The demo's situation: a 720p phone-class rolling-shutter calibration (20 ms readout)
    at 256 x 192, real shake, mild noise. Without recentring the shipped weights made such
    images worse (docs/gamd.md, "Rolling shutter"); with it the test image gains >= 1 dB."""
    from blurtrack.cli.demo import demo_dataset, demo_deblur
    from gamd.checkpoint import load_model
    from gamd.evaluate import psnr_ssim, restore
    from gamd.weights import shipped_weights

    data = tmp_path / "ds"
    demo_dataset(data, shared_data, count=4, size=(256, 192))
    s = demo_deblur(data, tmp_path / "demo")
    assert s["restored_psnr_db"] > s["blurred_psnr_db"] + 1.0
    # Negative control: the same weights without recentring do not reach it.
    model, config, _ = load_model(shipped_weights("gamd"))
    off = replace(config.data.restore_options(), recentre=False)
    ds = DeblurDataset(
        data,
        s["image"].split("/")[0],
        crop=None,
        augment=False,
        heat_scale_px=config.data.heat_scale_px,
    )
    item = ds.full(0)
    out = restore(model, item["blur"], item["heat"], off).permute(1, 2, 0).numpy()
    psnr_off = psnr_ssim(out, item["sharp"].permute(1, 2, 0).numpy())[0]
    assert psnr_off < s["restored_psnr_db"] - 1.0
