"""`gamd deblur` on the real DeepGyro SHIELD frames, with a before/after figure (issue 19;
docs/gamd.md "Real recording: DeepGyro SHIELD").

Steps (every one through the workbench's own commands where one exists):

1. ``blurtrack import deepgyro DATA S``; the session's camera readout is then set to the value
   DeepGyro publishes for the device (24.4944 ms) instead of the importer's 20 ms guess.
2. ``blurtrack calibrate S --fit timeshift --shift-window-ms 20``: intrinsics and readout held
   at the published values, only the time offset fitted, axes from the axis search. When it
   writes a calibration that is used. When it refuses (it does on this recording: 4 covered
   frame pairs do not determine the offset), the calibration is built from what its axis search
   measured (``axes.winner`` of its failure summary: R_cam_imu and the time offset) plus the
   published intrinsics and readout; nothing else.
3. ``blurtrack predict S --calib C.yaml --skip-uncovered`` (heat maps of the covered frames),
   ``gamd deblur S --heat P --skip-missing`` with the shipped GAMD weights and, as a control,
   the shipped heat-free GAMD-only weights (same restoration: gate, working resolution,
   recentring).
4. No-reference measures per covered frame, on gray in [0, 1], in the interior (a margin of
   ``--margin`` px left out, wider than the largest recentring offset, so the border padding of
   the resampling does not count): Laplacian variance and gradient energy (mean squared Sobel
   gradient, kernel normalised by 1/8), at full resolution and at the frame's working resolution
   (image area-downsampled by the working scale the restorer chose), for the blurred input, the
   recentred input alone (gamd.restorer.recentre: what the network is given) and both outputs;
   mean |output − input| and |output − recentred input| (8-bit levels) and the share of pixels
   the do-no-harm gate leaves closed (output = input there).

    PYTHONPATH=$PWD .venv/bin/python bench/deepgyro_deblur.py \
        [--figure docs/figures/deepgyro_deblur.jpg] [--out results.json]

Prints JSON. About 2 minutes on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch
import yaml
from json_out import emit

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "real" / "deepgyro-shield"
DEFAULT_FIGURE = REPO / "docs" / "figures" / "deepgyro_deblur.jpg"
#: DeepGyro's published readout for the NVIDIA SHIELD tablet (preprocess/calibration.py), s.
DEEPGYRO_READOUT_S = 0.0244944
NETS = ("gamd", "gamd_only")


def set_readout(session_dir: Path, readout_s: float) -> None:
    """Replace the imported session's readout guess with the published value."""
    path = session_dir / "session.yaml"
    meta = yaml.safe_load(path.read_text())
    meta["camera"]["readout_s"] = float(readout_s)
    meta["import"]["assumptions"]["readout_s"] = f"{readout_s} (DeepGyro's published value)"
    path.write_text(yaml.safe_dump(meta, sort_keys=False))


def calibration(bt, session_dir: Path, calib_path: Path, window_ms: float) -> dict:
    """Write ``calib_path``: calibrate's own result, or its axis search + published values."""
    from blurtrack.io.calibration import write_calibration
    from blurtrack.io.session import load_session

    args = ["calibrate", str(session_dir), "--out", str(calib_path), "--fit", "timeshift"]
    rc = bt([*args, "--shift-window-ms", str(window_ms)])
    if rc == 0 and calib_path.is_file():
        return {"source": "blurtrack calibrate --fit timeshift", "rc": rc}
    failed = json.loads(calib_path.with_name(calib_path.stem + ".failed.summary.json").read_text())
    winner = failed["axes"]["winner"]
    initial = load_session(session_dir).initial_calibration()
    calib = replace(
        initial,
        R_cam_imu=np.asarray(winner["R_cam_imu"], dtype=float),
        timeshift_cam_imu_s=float(winner["timeshift_s"]),
    )
    write_calibration(calib, calib_path)
    return {
        "source": "axis search of blurtrack calibrate (R_cam_imu, time offset) + published "
        "intrinsics and readout",
        "calibrate_rc": rc,
        "calibrate_refused": failed["warnings"],
        "timeshift_only_fit_s": failed["values"]["timeshift_s"],
        "timeshift_only_fit_sigma_s": failed["sigma"].get("timeshift_s"),
        "axis_margin": failed["axes"]["margin"],
        "axis_pairs": failed["axes"]["n_pairs"],
        "axis_score_px": winner["score_px"],
    }


def gray(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.float32), cv2.COLOR_RGB2GRAY)


def sharpness(g: np.ndarray) -> dict[str, float]:
    """Laplacian variance and gradient energy of a gray image in [0, 1]."""
    lap = cv2.Laplacian(g, cv2.CV_32F)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return {"lap_var": float(lap.var()), "grad_energy": float(np.mean(gx**2 + gy**2))}


def measure_frame(blur: np.ndarray, heat: np.ndarray, outs: dict, options, margin: int) -> dict:
    """All measures of one frame (RGB float images, heat maps in px)."""
    from gamd.restorer import blur_length_px, centre_offset, gate, recentre, working_scale

    ht = torch.from_numpy(heat)[None]
    (rec,), _ = recentre([torch.from_numpy(blur).permute(2, 0, 1)[None]], ht)
    rec_np = rec[0].permute(1, 2, 0).numpy()
    h, w = blur.shape[:2]
    scale = working_scale(ht[0], options.work_blur_px, min(h, w) / 32)
    size = (round(w / scale), round(h / scale))
    m = margin
    images = {"input": blur, "recentred_input": rec_np, **outs}
    res: dict = {
        "working_scale": scale,
        "working_size": list(size),
        "blur_length_px_median": float(blur_length_px(ht).median()),
        "centre_offset_px_max": float(torch.hypot(*centre_offset(ht)[0]).max()),
        "gate_closed_fraction": float((gate(ht, options.gate_px) < 1e-6).float().mean()),
    }
    for name, im in images.items():
        g = gray(im)
        small = cv2.resize(g, size, interpolation=cv2.INTER_AREA)
        ms = max(1, round(m / scale))
        res[name] = {
            "full": sharpness(g[m:-m, m:-m]),
            "working": sharpness(small[ms:-ms, ms:-ms]),
        }
    q = {k: np.round(np.clip(v, 0, 1) * 255) for k, v in images.items()}
    for name in outs:
        res[name]["mean_abs_change_vs_input"] = float(np.abs(q[name] - q["input"]).mean())
        res[name]["mean_abs_change_vs_recentred"] = float(
            np.abs(q[name] - q["recentred_input"]).mean()
        )
        res[name]["identical_to_input_fraction"] = float(
            (np.abs(q[name] - q["input"]).max(axis=2) == 0).mean()
        )
    res["_recentred"] = rec_np
    return res


def label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.rectangle(out, (0, 0), (8 + 9 * len(text), 22), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def overlay(bgr: np.ndarray, heat: np.ndarray, step: int = 240) -> np.ndarray:
    """Blur segments q(0)..q(1) (relative to each grid pixel) drawn on the image."""
    out = bgr.copy()
    h, w = bgr.shape[:2]
    for y in range(step // 2, h, step):
        for x in range(step // 2, w, step):
            p0 = (int(x + heat[0, y, x]), int(y + heat[1, y, x]))
            p1 = (int(x + heat[2, y, x]), int(y + heat[3, y, x]))
            cv2.line(out, p0, p1, (0, 255, 255), 5, cv2.LINE_AA)
            cv2.circle(out, (x, y), 10, (0, 0, 255), -1, cv2.LINE_AA)
    return out


def _bgr(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)


def _row(parts: list[np.ndarray]) -> np.ndarray:
    gap = np.full((parts[0].shape[0], 4, 3), 255, np.uint8)
    out = [parts[0]]
    for p in parts[1:]:
        out += [gap, p]
    return np.concatenate(out, axis=1)


def figure(
    path: Path,
    blur: np.ndarray,
    rec: np.ndarray,
    outs: dict[str, np.ndarray],
    heat: np.ndarray,
    crop: tuple[int, int, int, int],
    scale: float,
) -> None:
    """Three rows of three panels. Row 1, whole frame: input with blur segments | recentred
    input | GAMD output; row 2: the same at 1:1 in the crop; row 3: the working resolution
    (area-downsampled by ``scale``, shown enlarged without interpolation): recentred input |
    GAMD | GAMD-only, where the networks act."""
    x, y, cw, ch = crop
    b, r, o = _bgr(blur), _bgr(rec), _bgr(outs["gamd"])
    names = ["input + blur q(0)..q(1), dot = pixel", "recentred input", "GAMD output"]
    thumbs, crops = [], []
    for im, name in zip((overlay(b, heat), r, o), names, strict=True):
        t = im.copy()
        cv2.rectangle(t, (x, y), (x + cw, y + ch), (255, 0, 255), 4)
        th = round(cw * t.shape[0] / t.shape[1])
        thumbs.append(label(cv2.resize(t, (cw, th), interpolation=cv2.INTER_AREA), name))
    for im, name in zip((b, r, o), ("input", "recentred input", "GAMD output"), strict=True):
        crops.append(label(im[y : y + ch, x : x + cw], name + ", 1:1 crop"))
    h, w = blur.shape[:2]
    size = (round(w / scale), round(h / scale))
    small = []
    for im, name in zip(
        (rec, outs["gamd"], outs["gamd_only"]),
        ("recentred input", "GAMD", "GAMD-only (no heat)"),
        strict=True,
    ):
        s = cv2.resize(_bgr(im), size, interpolation=cv2.INTER_AREA)
        big = cv2.resize(s, (cw, round(cw * size[1] / size[0])), interpolation=cv2.INTER_NEAREST)
        small.append(label(big, f"{name}, working res. 1/{scale:.1f}"))
    rows = [_row(thumbs), _row(crops), _row(small)]
    sep = np.full((4, rows[0].shape[1], 3), 255, np.uint8)
    img = np.concatenate([rows[0], sep, rows[1], sep, rows[2]], axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 88]):
        raise OSError(f"cannot write {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--figure", type=Path, default=DEFAULT_FIGURE)
    ap.add_argument("--figure-frame", type=int, default=0, help="index among covered frames")
    ap.add_argument("--crop", default="1330,140,560,315", help="x,y,w,h of the 1:1 crop")
    ap.add_argument("--margin", type=int, default=100, help="border left out of measures (px)")
    ap.add_argument("--shift-window-ms", type=float, default=20.0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--work", type=Path, default=None, help="keep intermediate outputs in this new folder"
    )
    args = ap.parse_args(argv)
    from blurtrack.cli import main as bt
    from blurtrack.io.session import load_session
    from gamd.checkpoint import load_model
    from gamd.cli import main as gamd_cli
    from gamd.data import read_heat
    from gamd.infer import frame_to_rgb
    from gamd.weights import shipped_weights

    crop = tuple(int(v) for v in args.crop.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work if args.work is not None else Path(tmp)
        sess, calib_path, pred = work / "shield", work / "calib.yaml", work / "pred"
        if bt(["import", "deepgyro", str(args.data), str(sess)]) != 0:
            return 2
        set_readout(sess, DEEPGYRO_READOUT_S)
        cal = calibration(bt, sess, calib_path, args.shift_window_ms)
        cal["written"] = yaml.safe_load(calib_path.read_text())["cam0"]
        if bt(["predict", str(sess), "--calib", str(calib_path), "--out", str(pred),
               "--skip-uncovered", "--quiet"]) != 0:  # fmt: skip
            return 2
        for net in NETS:
            rc = gamd_cli(["deblur", str(sess), "--net", net, "--heat", str(pred),
                           "--out", str(work / net), "--skip-missing"])  # fmt: skip
            if rc != 0:
                return 2
        _, config, _ = load_model(shipped_weights("gamd"))
        options = config.data.restore_options()
        session = load_session(sess)
        summary = json.loads((work / "gamd" / "summary.json").read_text())
        frames, fig_done = [], False
        for i, ts in enumerate(session.frames["timestamp_ns"].to_numpy(np.int64)):
            if int(ts) not in summary["frames"]:
                continue
            blur = frame_to_rgb(session.read_image(i))
            heat = read_heat(pred / "heat" / f"{ts}.npy", blur.shape[:2])
            outs = {n: frame_to_rgb(cv2.imread(str(work / n / f"{ts}.png"))) for n in NETS}
            res = measure_frame(blur, heat, outs, options, args.margin)
            rec = res.pop("_recentred")
            if len(frames) == args.figure_frame:
                figure(args.figure, blur, rec, outs, heat, crop, res["working_scale"])
                fig_done = True
            frames.append({"timestamp_ns": int(ts), **res})
    result = {
        "calibration": cal,
        "restore_options": {k: getattr(options, k) for k in vars(options)},
        "frames": frames,
        "skipped": summary["skipped"],
        "figure": str(args.figure) if fig_done else None,
    }
    return emit(result, args.out, indent=2)


if __name__ == "__main__":
    sys.exit(main())
