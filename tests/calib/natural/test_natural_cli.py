"""``blurtrack calibrate`` on natural-scene sessions: what it refuses to write."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from blurtrack.cli import main
from blurtrack.errors import ConfigError
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.camera import Camera
from blurtrack.io.calibration import read_calibration, write_calibration
from calib.errors import CalibError
from calib.natural.cli import check_determined
from calib.uncertainty import UNDETERMINED_FACTOR, WEAK_SIGMA


def _fit(status: str = "ok", **sigma: float) -> SimpleNamespace:
    return SimpleNamespace(status=status, fitted=tuple(sigma), sigma=sigma)


def test_a_fit_with_an_undetermined_parameter_is_refused() -> None:
    edge = UNDETERMINED_FACTOR * WEAK_SIGMA["fx"]
    check_determined(_fit(timeshift_s=2e-4, fx=edge), 300)  # at the limit: written
    with pytest.raises(CalibError, match=r"does not determine fx \(sigma 501\) from 7 frames"):
        check_determined(_fit(timeshift_s=2e-4, fx=edge + 1), 7)
    with pytest.raises(CalibError, match=r"readout_s \(sigma nan\)"):
        check_determined(_fit(readout_s=float("nan")), 7)
    many = {k: 1e9 for k in ("timeshift_s", "fx", "fy", "cx", "cy")}
    tail = "fy (sigma 1e+09) and 2 more from 7 frames; no calibration written"
    with pytest.raises(CalibError, match=re.escape(tail)):
        check_determined(_fit(**many), 7)
    check_determined(_fit("failed", fx=1e9), 7)  # a failed fit is reported as failed


def test_deepgyro_recording_is_not_calibrated_from_four_covered_pairs(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = tmp_path / "dg"
    src = shared_data / "real" / "deepgyro-shield"
    assert main(["import", "deepgyro", str(src), str(session)]) == 0
    out = tmp_path / "out" / "calib.yaml"
    argv = ["calibrate", str(session), "--out", str(out), "--shift-window-ms", "20"]
    assert main(argv) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "does not determine timeshift_s" in err[0]
    # the axes the images decided are still reported (the winner of docs/natural.md)
    assert (
        "axis search (feature tracks" in cap.out
        and "[[0, -1, 0], [-1, 0, 0], [0, 0, -1]]" in cap.out
    )
    assert not out.exists() and not out.with_name("calib.summary.json").exists()
    # ... and written where a user can take them: a calibration file marked partial
    partial = out.with_name("calib.partial.yaml")
    assert f"are in {partial}, marked partial" in err[0]
    cal = read_calibration(partial)
    assert cal.partial is not None and "axes" in cal.partial["decided"]
    assert cal.R_cam_imu.tolist() == [[0, -1, 0], [-1, 0, 0], [0, 0, -1]]
    # predict and its overlays take it, labelled as partial
    pred = tmp_path / "pred"
    argv = ["predict", str(session), "--calib", str(partial), "--out", str(pred)]
    assert main([*argv, "--overlays", "2", "--skip-uncovered", "--quiet"]) == 0
    assert "predict: PARTIAL calibration" in capsys.readouterr().out
    summary = json.loads((pred / "summary.json").read_text())
    assert summary["partial"]["decided"] == cal.partial["decided"]
    assert len(summary["overlays"]["written"]) + len(summary["overlays"]["skipped"]) == 2
    # a second run does not replace the partial file without --force
    assert main(["calibrate", str(session), "--out", str(out), "--shift-window-ms", "20"]) == 2
    assert "exists" in capsys.readouterr().err


def test_partial_calibration_round_trips_and_a_fit_has_none(tmp_path: Path) -> None:
    cam = Camera((64, 48), (60.0, 60.0, 31.5, 23.5))
    base = Calibration(cam)
    assert base.partial is None and base.partial_label is None
    write_calibration(base, tmp_path / "fit.yaml")
    assert "partial" not in (tmp_path / "fit.yaml").read_text()
    part = base.with_(partial={"decided": "axes", "reason": "too short"})
    write_calibration(part, tmp_path / "p.yaml")
    back = read_calibration(tmp_path / "p.yaml")
    assert back.partial == {"decided": "axes", "reason": "too short"}
    assert back.partial_label == "PARTIAL calibration: axes only (too short)"
    with pytest.raises(ConfigError, match="partial"):
        base.with_(partial={"decided": 3})


def _phone_layout(src: Path, dst: Path, crop_rows: tuple[int, int] | None = None) -> Path:
    """The phone drive's layout under ``dst``: frames linked (or cropped to ``crop_rows``),
    frame times and gyro copied so a test can change them."""
    import cv2

    (dst / "frames").mkdir(parents=True)
    for img in sorted((src / "frames").glob("*.jpg")):
        if crop_rows is None:
            (dst / "frames" / img.name).symlink_to(img)
        else:
            a, b = crop_rows
            cv2.imwrite(str(dst / "frames" / (img.stem + ".png")), cv2.imread(str(img))[a:b])
    for name in ("framestamp.txt", "gyro.txt"):
        (dst / name).write_text((src / name).read_text())
    return dst


@pytest.mark.parametrize("case", ["gyro of another part of the drive", "only the dashboard"])
def test_phone_drive_without_a_static_scene_or_its_own_gyro_is_refused(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    """Negative controls of the common-heading model on the real drive: the gyro log moved by
    1.5 s (its rotations are another stretch of the drive's), and the frames cropped to the
    dashboard (rigid with the camera: nothing static turns). Both refused, nothing written."""
    src = shared_data / "real" / "phone-video-412hz"
    cy = 309.01
    if case.startswith("gyro"):
        lay = _phone_layout(src, tmp_path / "lay")
        rows = [r.split(",") for r in (lay / "gyro.txt").read_text().split()]
        moved = [f"{x},{y},{z},{float(t) - 1.5:.9f}" for x, y, z, t in rows]
        (lay / "gyro.txt").write_text("\n".join(moved) + "\n")
    else:
        lay = _phone_layout(src, tmp_path / "lay", crop_rows=(420, 600))
        cy -= 420
    session, out = tmp_path / "S", tmp_path / "out" / "c.yaml"
    k = f"573.85,575.04,406.01,{cy}"
    argv = ["import", "frames", str(lay), str(session), "--exposure-ms", "5.1", "--intrinsics", k]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["calibrate", str(session), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the common-heading model does not decide either" in err[0]
    assert not out.parent.exists() or not any(out.parent.iterdir())


@pytest.mark.parametrize(
    ("given", "message"),
    [
        (["1,2,3"], "must be X0,Y0,X1,Y1"),
        (["10,10,5,20"], "empty or outside"),
        (["900,10,950,20"], "empty or outside"),
        (["-5,-5,900,700"], "covers the whole"),
    ],
)
def test_bad_masks_are_refused(given: list[str], message: str) -> None:
    from calib.natural.cli import parse_mask

    with pytest.raises(CalibError, match=message):
        parse_mask(given, (800, 600))
    assert parse_mask(["0,420,799,599", "700,0,800,50"], (800, 600)) == (
        (0.0, 420.0, 799.0, 599.0),
        (700.0, 0.0, 800.0, 50.0),
    )
