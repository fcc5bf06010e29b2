"""Anchored placement of the modal template on fragments (blurtrack.detect.separation.anchored), on
the real photograph night2.jpg (skipped without the shared data)."""

from __future__ import annotations

import numpy as np
import pytest

import blurtrack.detect.frame as frame_mod
from blurtrack.detect import detect_frame
from blurtrack.detect.lines.measure import Measured


def _classes(fs, ref: np.ndarray) -> tuple[int, int]:
    """Whole streaks (vector within 25 % of ``ref``, either sign) and fragments (chord under
    0.75 of it), unclipped."""
    d = fs.end_b - fs.end_a
    dev = np.minimum(np.hypot(*(d - ref).T), np.hypot(*(d + ref).T))
    L = float(np.hypot(*ref))
    ok = ~fs.flags["clipped"]
    whole = ok & (dev <= 0.25 * L)
    frag = ok & ~whole & (np.hypot(*d.T) < 0.75 * L)
    return int(whole.sum()), int(frag.sum())


def test_faint_fragments_are_placed_whole(shared_data, monkeypatch: pytest.MonkeyPatch) -> None:
    import cv2

    image = cv2.imread(str(shared_data / "real" / "light-streaks" / "night2.jpg"))
    ref = np.array([4.4, 33.6])  # the photo's whole-component reference (docs/journal/detection.md)
    calls: list[int] = []
    real = frame_mod.anchored

    def counted(*args, **kwargs) -> tuple[Measured, int]:
        m, n = real(*args, **kwargs)
        calls.append(n)
        return m, n

    monkeypatch.setattr(frame_mod, "anchored", counted)
    whole, frag = _classes(detect_frame(image), ref)
    assert calls and calls[0] >= 3
    # Negative control: without the pass these fragments stay fragments.
    monkeypatch.setattr(frame_mod, "anchored", lambda ctx, m, *a, **k: (m, 0))
    whole0, frag0 = _classes(detect_frame(image), ref)
    assert whole >= whole0 + 3
    assert frag <= frag0 - 3
