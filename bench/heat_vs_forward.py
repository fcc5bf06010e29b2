"""Heat maps (q(0), q(1)) against DeepGyro-style forward-displacement blur fields, on the real
DeepGyro SHIELD frames (issue 19; docs/gamd.md "Heat maps and DeepGyro blur fields").

DeepGyro's blur field stores, per pixel ``x`` of row ``r``, the *forward displacement*
``f(x) = warp(x, t_r → t_r + exposure) − x``: where the scene point seen at ``x`` when the row
starts exposing is seen when it stops (rounded to whole pixels, and sign-flipped so that the
y component is ≤ 0, i.e. an undirected segment). Our heat maps store ``q(0)`` and ``q(1)``
with ``x + q(τ) = warp(x, t_r + τ·exposure → t_ref)``: positions in the *reference* (sharp)
image of what ``x`` collects. ``d = q(1) − q(0)`` is to first order ``−f`` (opposite sign),
and the two differ beyond that because ``d`` is measured in the reference frame while ``f`` is
anchored at ``x`` at the start of exposure.

The calibration: the session's published intrinsics, the camera–IMU axes and time offset
decided from the images by the axis search (``calib.natural.pipeline.discover_axes``, as
``blurtrack calibrate`` does; the continuous fit is not determined by these 7 frames, see
docs/natural.md), and the readout DeepGyro publishes for the device (24.4944 ms).

    PYTHONPATH=$PWD .venv/bin/python bench/heat_vs_forward.py [--data DIR] [--out FILE.json]

Prints JSON: per covered frame and over all, medians and RMS (px) of ``|d|``, ``|d + f|``
(sign-corrected difference), ``|d − f|`` (taking ``q(1) − q(0)`` as the forward displacement),
and the undirected distance ``min(|d − f|, |d + f|)`` DeepGyro's sign-normalised field allows.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from json_out import emit

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "real" / "deepgyro-shield"
#: DeepGyro's published readout for the NVIDIA SHIELD tablet (preprocess/calibration.py), s.
DEEPGYRO_READOUT_S = 0.0244944


def shield_calibration(session, window_s: float):
    """The session's published intrinsics with axes and time offset from the axis search."""
    from blurtrack.features.tracks import TrackParams, track_frames
    from calib.natural.pipeline import discover_axes, image_rotations, tracks_to_streaks

    frames = session.frames
    ts = frames["timestamp_ns"].to_numpy(np.int64)
    exp = frames["exposure_ns"].to_numpy(np.int64)
    tracks = track_frames(session.read_image, ts.size, TrackParams())
    initial = session.initial_calibration()
    rots = image_rotations(tracks, ts, exp, initial)
    t0 = tracks_to_streaks(tracks, ts, exp).t0_s
    search, start = discover_axes(rots, session.gyro(), t0, initial, window_s, "feature tracks")
    cam = replace(start.camera, readout_s=DEEPGYRO_READOUT_S)
    return replace(start, camera=cam), search


def _stats(v: np.ndarray) -> dict[str, float]:
    return {
        "median": float(np.median(v)),
        "rms": float(np.sqrt(np.mean(v**2))),
        "p95": float(np.percentile(v, 95)),
    }


def compare(session, calib, stride: int = 16, n_t: int = 16) -> dict:
    """Per frame the heat maps' ``d = q(1) − q(0)`` against the forward displacement."""
    from blurtrack.geometry.blur_model import BlurModel
    from blurtrack.synth.predict import uncovered_frames

    model = BlurModel(calib, session.gyro())
    bad = set(uncovered_frames(session, model))
    cam = model.camera
    W, H = cam.resolution
    xs, ys = np.arange(0, W, stride, dtype=float), np.arange(0, H, stride, dtype=float)
    gx, gy = np.meshgrid(xs, ys)
    px = np.stack([gx.ravel(), gy.ravel()], axis=1)
    per_frame: list[dict] = []
    pooled: dict[str, list[np.ndarray]] = {k: [] for k in ("d", "sum", "diff", "undirected")}
    for i, ts in enumerate(session.frames["timestamp_ns"].to_numpy(np.int64)):
        if int(ts) in bad:
            continue
        t, e = float(session.frame_times_s[i]), float(session.exposures_s[i])
        heat, _ = model.heat_maps(t, e, n_t, None, stride=1 if stride == 1 else 8)
        d = (heat[2:4] - heat[0:2])[:, gy.astype(int), gx.astype(int)].reshape(2, -1).T
        t_start = cam.row_start_s(t, px[:, 1])
        f = model.warp(px, t_start, t_start + e) - px  # forward displacement, DeepGyro's field
        vals = {
            "d": np.hypot(*d.T),
            "sum": np.hypot(*(d + f).T),
            "diff": np.hypot(*(d - f).T),
        }
        vals["undirected"] = np.minimum(vals["sum"], vals["diff"])
        for k, v in vals.items():
            pooled[k].append(v)
        per_frame.append({"timestamp_ns": int(ts), **{k: _stats(v) for k, v in vals.items()}})
    return {
        "frames": per_frame,
        "all": {k: _stats(np.concatenate(v)) for k, v in pooled.items() if v},
        "skipped_uncovered": sorted(bad),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--stride", type=int, default=16, help="pixel grid of the comparison")
    ap.add_argument("--shift-window-ms", type=float, default=20.0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    from blurtrack.cli import main as bt
    from blurtrack.io.session import load_session

    with tempfile.TemporaryDirectory() as tmp:
        sess_dir = Path(tmp) / "shield"
        if bt(["import", "deepgyro", str(args.data), str(sess_dir)]) != 0:
            return 2
        session = load_session(sess_dir)
        calib, search = shield_calibration(session, args.shift_window_ms * 1e-3)
        res = compare(session, calib, args.stride)
    res["calibration"] = {
        "R_cam_imu": np.asarray(calib.R_cam_imu).tolist(),
        "timeshift_cam_imu_s": calib.timeshift_cam_imu_s,
        "readout_s": calib.camera.readout_s,
        "intrinsics": list(calib.camera.intrinsics),
        "axis_margin": search.margin,
    }
    return emit(res, args.out, indent=2)


if __name__ == "__main__":
    sys.exit(main())
