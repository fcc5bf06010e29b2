"""The calibration files ``blurtrack calibrate`` writes: the calibration YAML, its OpenVINS and
camera_info twins, and the fit's summary (used by :mod:`calib.cli` and
:mod:`calib.natural.cli`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from blurtrack.cli.sources import summary_path
from blurtrack.io.calibration import write_calibration


def write_summary(res: Any, summary: dict, out: Path) -> Path:
    """Write the fit's summary beside ``out``; a failed fit writes ``<stem>.failed.summary.json``
    and never replaces the summary of the calibration it leaves in place. Returns the path."""
    from blurtrack.io.atomic import write_json_atomic

    failed = res.status == "failed"
    details = out.with_name(out.stem + ".failed.summary.json") if failed else summary_path(out)
    write_json_atomic(details, summary, default=float)  # strict JSON: NaN becomes null
    return details


def write_results(res: Any, out: Path, details: Path) -> str:
    """Refuse a failed fit (one line naming its summary), else write the calibration and its
    OpenVINS and camera_info twins; returns the line the command prints."""
    from calib.errors import CalibError
    from calib.export import write_camera_info, write_openvins

    if res.status == "failed":
        raise CalibError(
            "calibration failed: "
            + "; ".join(res.warnings)
            + f" (details in {details}; no calibration written)"
        )
    write_calibration(res.calibration, out)  # a fitted gyro scale is its gyro_scale_matrix
    write_openvins(res.calibration, out.with_name(out.stem + ".openvins.yaml"))
    write_camera_info(res.calibration, out.with_name(out.stem + ".camera_info.yaml"))
    return f"wrote {out} (+ .openvins.yaml, .camera_info.yaml, .summary.json)"
