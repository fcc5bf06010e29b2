"""Does the gyro-predicted blur of the real DeepGyro SHIELD frames follow the blur visible in
each frame? (issue 13, real-data target; docs/journal/natural.md "Real data").

Every tile's blur is measured from the tile alone (blurtrack.features.blur_estimate: power
cepstrum, no gyro) and compared with the blur the gyro predicts there under a candidate
calibration (BlurModel.point_track of the tile centre over its row's exposure):

* **kernel score**: normalised cross-correlation of the tile's cepstrum with the predicted
  (curved) kernel's, mean over tiles; no straight-line assumption, no length to read off;
* **blur vectors**: the tile's best straight blur (sign-free) against the predicted chord
  ``q(1) - q(0)``; endpoint difference in full-resolution px, after one common gain fitted in
  closed form (the ~1.2 the inter-frame tracks see), and direction difference in degrees.

Calibrations: the axis search of ``blurtrack calibrate`` (bench/deepgyro_deblur.calibration:
R_cam_imu and +22 ms from inter-frame tracks, published intrinsics and readout 24.49 ms), scans
of the time offset jointly with a gain on fx = fy (the offset's profile: best gain at each
offset), of the readout at the best offset and on an offset x readout grid, of a gain on fx or
on the gyro rates, and the importer's axes and the axis search's runner-up as negative controls.
Only tiles whose rows' exposures the gyro covers for every candidate of a scan count: the
"wide" scan (offset -40..+60 ms) leaves frames 3-4, the "narrow" one (-10..+40 ms) frames 2-5
(frame 5 without its bottom tiles). Uncertainty of the best offset: bootstrap over tiles (peak
of the resampled profile, parabola-refined) and the sandwich (M-estimator) sigma: per-tile score
slopes over the summed curvature at the peak.

    PYTHONPATH=$PWD .venv/bin/python bench/deepgyro_blur.py [--out results.json] \
        [--figure docs/figures/deepgyro_blur_agreement.jpg]

Prints JSON. About 15 minutes on 2 busy CPU cores with the docs/natural.md settings (the
straight-line search per tile and the offset x gain grid dominate).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from json_out import emit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from deepgyro_deblur import DEEPGYRO_READOUT_S, DEFAULT_DATA, calibration, set_readout

from blurtrack.features import blur_estimate as be
from blurtrack.geometry.blur_model import BlurModel
from blurtrack.geometry.calibration import Calibration
from blurtrack.geometry.gyro import GyroTrace
from blurtrack.io.calibration import read_calibration
from blurtrack.synth.photometry import decode_srgb8

REPO = Path(__file__).resolve().parents[1]
DEFAULT_FIGURE = REPO / "docs" / "figures" / "deepgyro_blur_agreement.jpg"
N_TAU = 16


@dataclass
class Tile:
    frame: int
    x0: int
    y0: int
    size: int
    cep: np.ndarray
    n_fft: int
    vec: be.BlurVector | None = None
    extra: dict = field(default_factory=dict)

    @property
    def centre(self) -> tuple[float, float]:
        return self.x0 + self.size / 2 - 0.5, self.y0 + self.size / 2 - 0.5


def gray_linear(bgr: np.ndarray) -> np.ndarray:
    """Gray linear light (the blur is a sum of light, not of sRGB codes)."""
    lin = decode_srgb8(bgr).astype(np.float64)
    return lin @ np.array([0.0722, 0.7152, 0.2126])  # BGR order


def covered(
    gyro,
    calib: Calibration,
    t_f: float,
    exp: float,
    y0: float,
    y1: float,
    shifts: tuple[float, float],
    readouts: tuple[float, float],
) -> bool:
    """Whether the gyro covers rows y0..y1 for every offset and readout of the ranges."""
    H = calib.camera.height
    lo = t_f + min(readouts) * y0 / H + min(shifts)
    hi = t_f + max(readouts) * y1 / H + exp + max(shifts)
    return bool(gyro.t_s[0] <= lo and hi <= gyro.t_s[-1])


def make_tiles(
    session, calib, scale: float, size: int, radius: int, shifts, readouts, vectors: bool
) -> list[Tile]:
    gyro = session.gyro()
    W, H = calib.camera.resolution
    out: list[Tile] = []
    T = round(size * scale)
    for i in range(len(session.frames)):
        t_f, exp = float(session.frame_times_s[i]), float(session.exposures_s[i])
        small = None
        for y0 in range(0, H - size + 1, size // 2):
            if not covered(gyro, calib, t_f, exp, y0, y0 + size, shifts, readouts):
                continue
            if small is None:
                g = gray_linear(session.read_image(i))
                small = cv2.resize(
                    g, (round(W * scale), round(H * scale)), interpolation=cv2.INTER_AREA
                )
            for x0 in range(0, W - size + 1, size // 2):
                sx, sy = round(x0 * scale), round(y0 * scale)
                tile = small[sy : sy + T, sx : sx + T]
                cep = be.tile_cepstrum(tile, radius)
                if cep is None:
                    continue
                t = Tile(i, x0, y0, size, cep, be.fft_size(tile.shape))
                if vectors:
                    t.vec = be.estimate_blur_vector(tile, radius=radius)
                out.append(t)
    return out


def trajectories(session, calib: Calibration, tiles: list[Tile], gyro_gain: float = 1.0):
    """Predicted trajectories ``(N, N_TAU, 2)`` (full-res px) of the tile centres, with the
    measured rates multiplied by ``gyro_gain``."""
    g = session.gyro()
    model = BlurModel(calib, GyroTrace(g.t_s, g.omega_radps * gyro_gain), check_coverage=True)
    tau = np.linspace(0.0, 1.0, N_TAU)
    px = np.array([t.centre for t in tiles])
    times = np.empty((len(tiles), N_TAU))
    for k, t in enumerate(tiles):
        t_f, exp = float(session.frame_times_s[t.frame]), float(session.exposures_s[t.frame])
        times[k] = calib.camera.row_start_s(t_f, px[k, 1]) + exp * tau
    return model.point_track(px, times[:, N_TAU // 2], times)


def scores(tiles: list[Tile], q: np.ndarray, scale: float, radius: int) -> np.ndarray:
    """Kernel score of each tile against its predicted trajectory."""
    out = np.empty(len(tiles))
    size = 2 * radius + 1
    for k, t in enumerate(tiles):
        try:
            kern = be.rasterize(q[k] * scale, size)
        except be.BlurEstimateError:
            out[k] = -1.0  # longer than the map can show
            continue
        out[k] = be.kernel_score(t.cep, be.kernel_cepstrum(kern, radius, t.n_fft))
    return out


def vector_agreement(tiles: list[Tile], q: np.ndarray, scale: float) -> dict:
    """Measured straight blur vs predicted chord (sign-free), full-resolution px: direction
    difference, length ratio, endpoint difference at gain 1 and after the median length ratio
    as a common gain (robust to the estimator's gross length errors)."""
    idx = [k for k, t in enumerate(tiles) if t.vec is not None]
    if not idx:
        return {"n": 0}
    m = np.array([tiles[k].vec.vector_px for k in idx]) / scale
    p = q[idx, -1] - q[idx, 0]
    s = np.sign(np.sum(m * p, axis=1))
    s[s == 0] = 1
    ms = m * s[:, None]
    lp = np.linalg.norm(p, axis=1)
    ratio = np.linalg.norm(m, axis=1) / lp
    gain = float(np.median(ratio))
    e1 = np.linalg.norm(ms - p, axis=1)
    eg = np.linalg.norm(ms - gain * p, axis=1)
    ang = np.degrees(np.arctan2(p[:, 0] * ms[:, 1] - p[:, 1] * ms[:, 0], np.sum(p * ms, axis=1)))
    return {
        "n": len(idx),
        "n_undetermined": len(tiles) - len(idx),
        "median_abs_direction_deg": float(np.median(np.abs(ang))),
        "direction_abs_p25_p75_deg": np.percentile(np.abs(ang), [25, 75]).round(3).tolist(),
        "median_length_ratio": gain,
        "length_ratio_p25_p75": np.percentile(ratio, [25, 75]).round(4).tolist(),
        "median_predicted_length_px": float(np.median(lp)),
        "median_endpoint_px_gain1": float(np.median(e1)),
        "median_endpoint_px_median_gain": float(np.median(eg)),
        "share_endpoint_under_10pct_median_gain": float(np.mean(eg < 0.1 * gain * lp)),
    }


def evaluate(session, calib, tiles, scale, radius, gyro_gain: float = 1.0):
    """Per-tile kernel scores ``(N,)`` and predicted trajectories ``(N, N_TAU, 2)``."""
    q = trajectories(session, calib, tiles, gyro_gain)
    return scores(tiles, q, scale, radius), q


def peak(xs: np.ndarray, ys: np.ndarray) -> float:
    """Parabola-refined argmax of a sampled curve."""
    i = int(np.argmax(ys))
    if 0 < i < len(xs) - 1:
        a, b, _ = np.polyfit(xs[i - 1 : i + 2], ys[i - 1 : i + 2], 2)
        if a < 0:
            return float(np.clip(-b / (2 * a), xs[i - 1], xs[i + 1]))
    return float(xs[i])


def profile_peak(offsets: np.ndarray, S: np.ndarray) -> tuple[float, int]:
    """Best offset of per-tile scores ``S (offsets, gains, tiles)``: the mean over tiles,
    maximised over the gain at each offset (a profile), parabola-refined; and the gain index."""
    prof = S.mean(axis=2)
    best = peak(offsets, prof.max(axis=1))
    i = int(np.argmin(np.abs(offsets - best)))
    return best, int(np.argmax(prof[i]))


def offset_uncertainty(offsets, S, n_boot, rng) -> dict:
    """Bootstrap over tiles of the profile peak, and the sandwich (M-estimator) sigma of the
    offset at the best gain: per-tile slopes over the summed curvature of the scores."""
    best, k = profile_peak(offsets, S)
    T = S[:, k, :]
    i = int(np.clip(np.argmin(np.abs(offsets - best)), 1, len(offsets) - 2))
    h = offsets[i + 1] - offsets[i]
    g = (T[i + 1] - T[i - 1]) / (2 * h)
    c = float(np.sum(T[i + 1] - 2 * T[i] + T[i - 1]) / h**2)
    sigma = float(np.sqrt(np.sum(g**2)) / -c) if c < 0 else float("inf")
    n = S.shape[2]
    boot = [profile_peak(offsets, S[:, :, rng.integers(0, n, n)])[0] for _ in range(n_boot)]
    return {
        "best_ms": best * 1e3,
        "sigma_sandwich_ms": sigma * 1e3,
        "bootstrap_std_ms": float(np.std(boot) * 1e3),
        "bootstrap_p5_p95_ms": (np.percentile(boot, [5, 95]) * 1e3).round(2).tolist(),
        "bootstrap_at_range_edge": float(
            np.mean(np.isclose(boot, offsets[0]) | np.isclose(boot, offsets[-1]))
        ),
    }


def per_tile(session, calibs, tiles, scale, radius) -> np.ndarray:
    """Per-tile scores ``(len(calibs), tiles)`` of (calibration, gyro gain) pairs."""
    return np.array([evaluate(session, c, tiles, scale, radius, g)[0] for c, g in calibs])


def scan_1d(session, calib, tiles, scale, radius, name, values, make) -> dict:
    """Mean kernel score over ``values``; ``make(calib, v)`` gives (calibration, gyro gain)."""
    S = per_tile(session, [make(calib, v) for v in values], tiles, scale, radius)
    mean = S.mean(axis=1)
    return {
        name: np.round(values, 6).tolist(),
        "mean_score": mean.round(5).tolist(),
        "best": peak(values, mean),
    }


def with_fx_gain(calib: Calibration, g: float) -> tuple[Calibration, float]:
    fx, fy, cx, cy = calib.camera.intrinsics
    return calib.with_(intrinsics=(g * fx, g * fy, cx, cy)), 1.0


def with_gyro_gain(calib: Calibration, g: float) -> tuple[Calibration, float]:
    return calib, float(g)


def summary(session, calib, tiles, scale, radius, gyro_gain: float = 1.0) -> dict:
    s, q = evaluate(session, calib, tiles, scale, radius, gyro_gain)
    return {
        "mean_score": float(s.mean()),
        "median_score": float(np.median(s)),
        "vectors": vector_agreement(tiles, q, scale),
    }


def tile_list(tiles: list[Tile]) -> dict:
    out: dict[str, list] = {}
    for t in tiles:
        out.setdefault(f"frame {t.frame + 1}", []).append([t.x0, t.y0])
    return {k: {"n": len(v), "tile_origins_px": v} for k, v in out.items()}


def study(session, base, controls, tiles, args, shifts, rng) -> dict:
    sc, r, ms = args.scale, args.radius, 1e-3
    offsets = np.arange(shifts[0], shifts[1] + 1e-9, args.offset_step_ms * ms)
    gains = np.arange(args.gains[0], args.gains[1] + 1e-9, args.gains[2])
    res: dict = {"tiles": tile_list(tiles), "n_tiles": len(tiles)}
    res["gain_fx_at_axis_search"] = scan_1d(
        session, base, tiles, sc, r, "gain", gains, with_fx_gain
    )
    S = np.stack(
        [
            per_tile(
                session,
                [with_fx_gain(base.with_(timeshift_cam_imu_s=float(o)), g) for g in gains],
                tiles,
                sc,
                r,
            )
            for o in offsets
        ]
    )
    prof = S.mean(axis=2)
    res["offset_scan"] = {
        "offsets_ms": (offsets / ms).round(3).tolist(),
        "gains_fx": gains.round(4).tolist(),
        "profile_score": prof.max(axis=1).round(5).tolist(),
        "profile_gain": gains[np.argmax(prof, axis=1)].round(4).tolist(),
        "score_gain1": prof[:, int(np.argmin(np.abs(gains - 1.0)))].round(5).tolist(),
        **offset_uncertainty(offsets, S, args.boot, rng),
    }
    best_o = res["offset_scan"]["best_ms"] * ms
    best_g = float(gains[profile_peak(offsets, S)[1]])
    at = with_fx_gain(base.with_(timeshift_cam_imu_s=best_o), best_g)[0]
    readouts = np.arange(0.0, 35.0 + 1e-9, args.readout_step_ms) * ms
    res["readout_scan"] = scan_1d(
        session,
        at,
        tiles,
        sc,
        r,
        "readout_s",
        readouts,
        lambda c, v: (c.with_(readout_s=float(v)), 1.0),
    )
    sub = offsets[:: args.grid_every]
    G = np.array(
        [
            per_tile(
                session,
                [(at.with_(readout_s=float(ro), timeshift_cam_imu_s=float(o)), 1.0) for o in sub],
                tiles,
                sc,
                r,
            ).mean(axis=1)
            for ro in readouts
        ]
    )
    j, k = np.unravel_index(int(np.argmax(G)), G.shape)
    res["offset_readout_grid"] = {
        "gain_fx": best_g,
        "readouts_ms": (readouts / ms).round(3).tolist(),
        "offsets_ms": (sub / ms).round(3).tolist(),
        "mean_score": G.round(5).tolist(),
        "best_readout_ms": float(readouts[j] / ms),
        "best_offset_ms": float(sub[k] / ms),
    }
    res["gain_fx_at_best"] = scan_1d(
        session, base.with_(timeshift_cam_imu_s=best_o), tiles, sc, r, "gain", gains, with_fx_gain
    )
    res["gain_gyro_at_best"] = scan_1d(
        session, base.with_(timeshift_cam_imu_s=best_o), tiles, sc, r, "gain", gains, with_gyro_gain
    )
    g_ax = res["gain_fx_at_axis_search"]["best"]
    res["agreement"] = {
        "axis_search_22ms_gain1": summary(session, base, tiles, sc, r),
        "axis_search_22ms_fitted_gain": summary(session, with_fx_gain(base, g_ax)[0], tiles, sc, r),
        "best_offset_and_gain": summary(session, at, tiles, sc, r),
        "best_offset_gyro_gain": summary(
            session,
            base.with_(timeshift_cam_imu_s=best_o),
            tiles,
            sc,
            r,
            res["gain_gyro_at_best"]["best"],
        ),
    }
    for name, R in controls.items():
        res["agreement"][name] = summary(
            session, with_fx_gain(base.with_(R_cam_imu=R), g_ax)[0], tiles, sc, r
        )
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--figure", type=Path, default=DEFAULT_FIGURE)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--scale", type=float, default=1 / 3, help="working scale of the frames")
    ap.add_argument("--tile", type=int, default=384, help="tile side, full-resolution px")
    ap.add_argument("--radius", type=int, default=60, help="cepstrum radius, working px")
    ap.add_argument("--offset-step-ms", type=float, default=2.0)
    ap.add_argument("--readout-step-ms", type=float, default=5.0)
    ap.add_argument("--grid-every", type=int, default=2, help="offset subsampling of the grid")
    ap.add_argument("--boot", type=int, default=200)
    ap.add_argument("--gains", default="0.96,1.36,0.04", help="fx gain scan: first,last,step")
    ap.add_argument("--scans", default="wide,narrow")
    ap.add_argument("--figure-scan", default="narrow", help="whose tiles and best fit to draw")
    ap.add_argument("--no-vectors", action="store_true", help="skip the straight-line search")
    args = ap.parse_args(argv)
    args.gains = [float(v) for v in args.gains.split(",")]
    from blurtrack.cli import main as bt
    from blurtrack.io.session import load_session

    rng = np.random.default_rng(0)
    ranges = {"wide": (-0.040, 0.060), "narrow": (-0.010, 0.040)}
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(sys.stderr):
        sess, calib_path = Path(tmp) / "shield", Path(tmp) / "calib.yaml"
        if bt(["import", "deepgyro", str(args.data), str(sess)]) != 0:
            return 2
        set_readout(sess, DEEPGYRO_READOUT_S)
        cal_info = calibration(bt, sess, calib_path, 20.0)
        session = load_session(sess)
        base = read_calibration(calib_path)
        importer_R = session.initial_calibration().R_cam_imu
        cands = json.loads((Path(tmp) / "calib.failed.summary.json").read_text())["axes"]
        controls = {
            "importer_axes_negative_control": importer_R,
            "runner_up_axes_negative_control": np.array(cands["candidates"][1]["R_cam_imu"]),
        }
        result: dict = {
            "calibration": {
                k: cal_info[k] for k in ("source", "axis_margin", "axis_score_px") if k in cal_info
            },
            "R_cam_imu_axis_search": base.R_cam_imu.tolist(),
            "timeshift_axis_search_ms": base.timeshift_cam_imu_s * 1e3,
            "readout_ms": base.camera.readout_s * 1e3,
            **{f"R_cam_imu_{k}": v.tolist() for k, v in controls.items()},
            "scale": args.scale,
            "tile_px": args.tile,
            "radius_working_px": args.radius,
        }
        readouts = (0.0, 0.035)
        for name in args.scans.split(","):
            tiles = make_tiles(
                session,
                base,
                args.scale,
                args.tile,
                args.radius,
                ranges[name],
                readouts,
                not args.no_vectors,
            )
            result[name] = study(session, base, controls, tiles, args, ranges[name], rng)
            result[name]["offset_range_ms"] = [v * 1e3 for v in ranges[name]]
            if args.figure and name == args.figure_scan:
                from deepgyro_blur_figure import figure

                result["figure"] = figure(args.figure, session, base, tiles, result[name], args)
    return emit(result, args.out, indent=1)


if __name__ == "__main__":
    sys.exit(main())
