"""``blurtrack calibrate`` on natural-scene sessions: what it refuses to write."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from blurtrack.cli import main
from calib.errors import CalibError
from calib.natural_cli import check_determined
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
