"""``blurtrack import {deepgyro,marslogger} SRC OUT``: third-party recordings to sessions."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="convert a third-party recording into a session folder")
    p.add_argument("kind", choices=["deepgyro", "marslogger"], help="source format")
    p.add_argument("src", type=Path, help="source folder")
    p.add_argument("out", type=Path, help="new session folder (must not exist or be empty)")
    p.add_argument(
        "--overlays",
        type=int,
        default=0,
        metavar="N",
        help="also draw predicted trajectories over the first N frames",
    )
    p.set_defaults(func=run)


#: Stamped on overlays drawn with a guessed camera-IMU axis mapping.
GUESS_LABEL = "axes UNKNOWN: drawn with the importer's guess, not a calibration"


def label_image(path: Path, text: str) -> None:
    """Stamp ``text`` in a dark band across the top of the image file at ``path``."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return
    scale = max(img.shape[1] / 1600.0, 0.4)
    band = int(40 * scale)
    img[:band] = (img[:band] * 0.3).astype(img.dtype)
    cv2.putText(
        img,
        text,
        (int(10 * scale), int(28 * scale)),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        (0, 255, 255),
        max(1, int(2 * scale)),
        cv2.LINE_AA,
    )
    cv2.imwrite(str(path), img)


def run(args: argparse.Namespace) -> int:
    from blurtrack.io.importers import IMPORTERS
    from blurtrack.io.session import load_session
    from blurtrack.overlay import draw_session_overlays

    summary = IMPORTERS[args.kind](args.src, args.out)
    session = load_session(args.out)
    axes_known = session.meta.imu.axes_known
    summary["axes_known"] = axes_known
    if args.overlays:
        n = min(args.overlays, len(session.frames))
        summary["overlays"] = draw_session_overlays(
            session, session.initial_calibration(), args.out / "overlays", list(range(n))
        )
        if not axes_known:
            for path in summary["overlays"]["written"]:
                label_image(Path(path), GUESS_LABEL)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(
        f"imported {summary['frames']} frames and {summary['gyro_samples']} gyro samples "
        f"from {args.src} into {args.out}"
    )
    for key, text in summary["assumptions"].items():
        print(f"  assumed {key}: {text}")
    if not axes_known:
        print("  camera-IMU axes unknown: `blurtrack calibrate` searches the 24 signed axis maps")
    if args.overlays:
        ov = summary["overlays"]
        tag = " (labelled: drawn with the guessed axes)" if not axes_known else ""
        print(f"  overlays: {len(ov['written'])} written to {args.out / 'overlays'}{tag}")
        for i, why in ov["skipped"].items():
            print(f"  frame {i} not drawn: {why}")
    return 0
