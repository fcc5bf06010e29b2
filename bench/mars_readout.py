"""Can the MARS logger recording's readout be fitted? Its metadata says 5.63 ms.

``blurtrack calibrate`` refuses this recording (its axis search is undecided: margin below 2),
so it writes nothing. This diagnostic fits anyway from the search's winner
(``calibrate_natural(..., strict_axes=False)``), writes no calibration, and prints one JSON
document: for each ``--fit`` set, the fitted readout and time offset with their 1-sigma, the
track residuals, and the size of the image effect the metadata's readout would have (the
frames' median image speed times the readout: how far the last row's scene moves against the
first row's). A readout whose effect is well under the track residual cannot be fitted.

    PYTHONPATH=. python bench/mars_readout.py [--data ../shared/data/real/marslogger-phone]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from blurtrack.io.session import load_session
from calib.fit import FitOptions
from calib.natural.pipeline import calibrate_natural

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "real" / "marslogger-phone"
#: The natural default, and the time offset held where the axis search put it.
FITS = ("timeshift,fx,fy,cx,cy,readout,bias,rotation", "readout,bias,rotation")


def one_fit(session, fit: str) -> dict:
    nat = calibrate_natural(
        session, FitOptions(fit=fit, shift_window_s=0.06), translation="none", strict_axes=False
    )
    r = nat.result
    ts = session.frames["timestamp_ns"].to_numpy(np.int64)
    period_s = float(np.median(np.diff(ts))) * 1e-9
    speed_pxps = nat.summary()["features"]["displacement_px_median"] / period_s
    readout_meta_s = session.initial_calibration().camera.readout_s
    return {
        "fit": fit,
        "status": r.status,
        "axes_margin": nat.axes.margin,
        "axes_winner": nat.axes.R_cam_imu.tolist(),
        "readout_ms": 1e3 * r.values["readout_s"],
        "readout_sigma_ms": 1e3 * r.sigma.get("readout_s", float("nan")),
        "timeshift_ms": 1e3 * r.values["timeshift_s"],
        "timeshift_sigma_ms": 1e3 * r.sigma.get("timeshift_s", float("nan")),
        "metadata_readout_ms": 1e3 * readout_meta_s,
        "median_image_speed_pxps": speed_pxps,
        "metadata_readout_effect_px": speed_pxps * readout_meta_s,
        "track_residual_rms_px": r.train.rms_px,
        "holdout_rms_px": r.holdout.rms_px,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        s = Path(tmp) / "S"
        cmd = [sys.executable, "-m", "blurtrack", "import", "marslogger", str(args.data), str(s)]
        subprocess.run(cmd, check=True, capture_output=True, cwd=REPO)
        session = load_session(s)
        out = [one_fit(session, fit) for fit in FITS]
    print(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
