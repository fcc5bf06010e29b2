"""The overlay figure of bench/deepgyro_blur.py (docs/figures/deepgyro_blur_agreement.jpg):
blur measured from the frames themselves against the gyro's prediction, per tile."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from deepgyro_blur import Tile, trajectories, with_fx_gain

from blurtrack.geometry.calibration import Calibration


def figure(path: Path, session, base: Calibration, tiles: list[Tile], res: dict, args) -> str:
    """Two covered frames, half size, with per tile: the measured straight blur (cyan, centred
    on the tile centre, sign-free), the trajectory predicted with the best offset and gain
    (yellow) and with the axis search's +22 ms at gain 1 (red), each centred likewise."""
    o = res["offset_scan"]["best_ms"] * 1e-3
    g = float(res["offset_readout_grid"]["gain_fx"])
    best = with_fx_gain(base.with_(timeshift_cam_imu_s=o), g)[0]
    q_best = trajectories(session, best, tiles)
    q_ax = trajectories(session, base, tiles)
    have = sorted({t.frame for t in tiles})
    frames = [f for f in (2, 3) if f in have] or have[:2]  # frames 3 and 4 when covered
    panels = []
    for f in frames:
        img = session.read_image(f).copy()
        for k, t in enumerate(tiles):
            if t.frame != f:
                continue
            c = np.array(t.centre)
            for q, col, w in ((q_ax[k], (0, 0, 255), 11), (q_best[k], (0, 255, 255), 5)):
                pts = (q - 0.5 * (q[0] + q[-1]) + c).round().astype(np.int32)
                cv2.polylines(img, [pts], False, col, w, cv2.LINE_AA)
            if t.vec is not None:
                v = np.array(t.vec.vector_px) / args.scale
                p0, p1 = (c - v / 2).round().astype(int), (c + v / 2).round().astype(int)
                cv2.line(img, tuple(p0.tolist()), tuple(p1.tolist()), (255, 255, 0), 3, cv2.LINE_AA)
            cv2.circle(img, (round(c[0]), round(c[1])), 7, (255, 0, 255), -1, cv2.LINE_AA)
        small = cv2.resize(
            img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA
        )
        text = (
            f"frame {f + 1}: cyan = blur measured from the image; yellow = gyro, "
            f"{o * 1e3:+.0f} ms, fx x{g:.2f}; red = gyro, +22 ms, fx x1"
        )
        cv2.rectangle(small, (0, 0), (9 * len(text) // 1 + 8, 24), (0, 0, 0), -1)
        cv2.putText(
            small, text, (4, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA
        )
        panels.append(small)
    sep = np.full((4, panels[0].shape[1], 3), 255, np.uint8)
    out = np.concatenate([panels[0], sep, *panels[1:]], axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), out, [cv2.IMWRITE_JPEG_QUALITY, 85]):
        raise OSError(f"cannot write {path}")
    return str(path)
