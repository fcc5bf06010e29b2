"""A session as a camera that reads its bottom row first would record it (tests of the
rows' readout order, :mod:`blurtrack.detect.gyro.readout`)."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from blurtrack.io.turn import turn_session_files


def turn_session(src: Path, dst: Path) -> None:
    """``src`` copied to ``dst`` and turned by 180 degrees (:func:`turn_session_files`: the
    frames, the principal point and the axes; the readout keeps its number, the order being
    what no session file says), its truth's ends turned alike."""
    shutil.copytree(src, dst)
    turn_session_files(dst)
    meta = yaml.safe_load((dst / "session.yaml").read_text())
    w, h = meta["camera"]["resolution"]
    truth = yaml.safe_load((dst / "truth.yaml").read_text())
    for fr in truth["frames"]:
        for st in fr.get("streaks") or []:
            for key in ("start", "end"):
                st[key] = [w - 1 - st[key][0], h - 1 - st[key][1]]
    (dst / "truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False))
