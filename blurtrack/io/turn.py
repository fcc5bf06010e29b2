"""A session's frames turned by 180 degrees (``blurtrack import ... --turn-180``).

A sensor mounted upside down reads its bottom row first, which the session format (the top
row first, docs/conventions.md) cannot say; stored turned by 180 degrees, with its principal
point and camera axes turned alike, it reads the top row first and every command models it
as it is. ``blurtrack detect`` tells such frames from their streaks (its summary's
``gyro_readout_order``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from blurtrack.geometry.camera import TURN_180, turned_camera
from blurtrack.io.atomic import write_bytes_atomic
from blurtrack.io.session import SessionMeta, encode_frame, load_session
from blurtrack.io.yamlio import write_yaml


def turned_meta(meta: SessionMeta) -> SessionMeta:
    """``meta`` for its frames turned by 180 degrees: the camera turned
    (:func:`~blurtrack.geometry.camera.turned_camera`) and ``T_cam_imu`` pre-multiplied by
    ``diag(TURN_180, 1)`` (the camera's x and y axes reversed); all else as it is."""
    turn = np.eye(4)
    turn[:3, :3] = TURN_180
    return replace(
        meta,
        camera=turned_camera(meta.camera),
        imu=replace(meta.imu, T_cam_imu=turn @ meta.imu.T_cam_imu),
    )


def turn_session_files(folder: str | Path) -> int:
    """Turn the session being written at ``folder`` by 180 degrees where it lies: every frame
    (re-encoded as the lossless PNG it is stored as, each atomically) and ``session.yaml``
    (:func:`turned_meta`); returns the frames turned. For an importer's own, not yet
    published output only (the import's temporary folder): a recorded session is never
    rewritten."""
    folder = Path(folder)
    session = load_session(folder)
    for i in range(len(session.frames)):
        image = session.read_image(i)
        write_bytes_atomic(session.image_path(i), encode_frame(image[::-1, ::-1], f"frame {i}"))
    write_yaml(folder / "session.yaml", turned_meta(session.meta).to_dict())
    return len(session.frames)
