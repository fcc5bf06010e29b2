"""Can the MARS clip's own blur decide its camera–IMU axes? (issue 44, item 4; docs/natural.md)

The inter-frame tracks leave the axis search undecided (margin 1.79). Its frames are 240 ms
exposures, so each frame's blur is evidence too: every tile's power cepstrum (the tile alone,
no gyro; ``blurtrack.features.blur_estimate``) is compared with the cepstrum of the kernel the
gyro predicts at the tile's centre under each of the 24 candidates (``bench/deepgyro_blur.py``'s
tiles and scores, the session's intrinsics and readout), at time offsets -60..+60 ms in 20 ms
steps. A candidate's score is its best mean kernel score over the tiles. Prints JSON.

    blurtrack import marslogger ../shared/data/real/marslogger-phone S
    PYTHONPATH=$PWD .venv/bin/python bench/mars_blur_axes.py S [--out results.json]

About 5 minutes on 2 busy cores. A cepstrum is blind to a kernel's direction of travel, so two
candidates whose camera rates differ only in the signs of x and y (``diag(-1, -1, 1) · P``)
score nearly alike: the blur can separate the others only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from deepgyro_blur import evaluate, make_tiles
from json_out import emit

from blurtrack.io.session import load_session
from calib.axes.search import proper_axis_permutations

#: Tiles at half resolution: 384 px tiles (192 px) hold blurs up to the 48 px map radius.
SCALE, SIZE, RADIUS = 0.5, 384, 48
SHIFTS_S = np.arange(-0.06, 0.0601, 0.02)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path, help="the imported MARS session")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    session = load_session(args.session)
    init = session.initial_calibration()
    readout = (init.camera.readout_s, init.camera.readout_s)
    span = (float(SHIFTS_S.min()), float(SHIFTS_S.max()))
    tiles = make_tiles(session, init, SCALE, SIZE, RADIUS, span, readout, False)
    P = proper_axis_permutations()
    rows = []
    for c in range(len(P)):
        best: dict = {"score": -9.0}
        for shift in SHIFTS_S:
            cal = init.with_(R_cam_imu=P[c], timeshift_cam_imu_s=float(shift))
            sc, q = evaluate(session, cal, tiles, SCALE, RADIUS)
            if float(np.mean(sc)) > best["score"]:
                length = np.linalg.norm(q[:, -1] - q[:, 0], axis=1)
                best = {
                    "score": float(np.mean(sc)),
                    "shift_ms": float(shift * 1e3),
                    "predicted_chord_median_px": float(np.median(length)),
                }
        rows.append({"R_cam_imu": P[c].astype(int).tolist(), **best})
    rows.sort(key=lambda r: -r["score"])
    result = {
        "tiles": len(tiles),
        "frames": sorted({t.frame for t in tiles}),
        "best_over_runner_up": rows[0]["score"] / max(rows[1]["score"], 1e-12),
        "candidates": rows,
    }
    return emit(result, args.out)


if __name__ == "__main__":
    sys.exit(main())
