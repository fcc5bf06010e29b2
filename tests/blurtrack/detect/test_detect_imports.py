"""What detection imports, and when (the start-up cost of ``blurtrack detect``, issue 14).

Detecting a frame needs numpy and OpenCV only (no scipy at all: ``scipy.special`` alone costs
~0.25 s of serial start-up, before the workers fork): the table packages (pandas,
pyarrow) are imported where a session is loaded and the table is built and written,
scikit-image where a folded streak is thinned, and torch and scipy never (the gyro's spline
is written out, :mod:`blurtrack.geometry.spline`: ``scipy.interpolate`` cost 0.4-0.7 s).
Each check runs in a fresh interpreter and has a negative control (a module that does import
the package), so that it can fail.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from blurtrack.detect.lines.ragged import split_at
from blurtrack.detect.session.table import read_table
from blurtrack.testing.mini_session import write_synthetic_session

REPO = Path(__file__).resolve().parents[3]

#: Packages that detecting a frame does not need.
NOT_FOR_FRAMES = ("pandas", "pyarrow", "scipy.interpolate", "skimage", "torch", "matplotlib")


def _modules_after(code: str) -> set[str]:
    script = f"import sys\n{code}\nprint(' '.join(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, check=True
    )
    return set(out.stdout.split())


def _present(mods: set[str], names: tuple[str, ...]) -> list[str]:
    return sorted(n for n in names if n in mods)


def test_detecting_a_frame_imports_no_table_or_spline_package() -> None:
    code = (
        "import numpy as np\n"
        "from blurtrack.detect import DetectParams, detect_frame\n"
        "from blurtrack.testing.streak_frames import line, quantise, render_streaks\n"
        "curves = [line((20, 30), (60, 40)), line((90, 80), (130, 70))]\n"
        "img = quantise(render_streaks((120, 160), curves, 0.6, 1.3, 0.03, 0.004, 1))\n"
        "fs = detect_frame(img, DetectParams())\n"
        "assert len(fs) == 2, len(fs)"
    )
    mods = _modules_after(code)
    assert (
        "blurtrack.detect.separation.separate" in mods and "cv2" in mods
    )  # detection was imported
    assert _present(mods, NOT_FOR_FRAMES) == []
    # negative control: the session layer does import pandas
    assert _present(_modules_after("import blurtrack.detect.session.pipeline"), ("pandas",)) == [
        "pandas"
    ]


def test_the_detect_command_never_imports_torch_or_scipy(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_synthetic_session(folder, n_frames=3, seed=3)
    out = tmp_path / "t.parquet"
    code = (
        "from blurtrack.cli import main\n"
        f"rc = main(['detect', {str(folder)!r}, '--out', {str(out)!r}, '--workers', '1', "
        "'--quiet'])\n"
        "assert rc == 0"
    )
    mods = _modules_after(code)
    assert out.is_file() and {"pandas", "pyarrow.parquet"} <= mods  # the table was written
    # the gyro oriented streaks (so it was resampled through the spline)
    assert "gyro" in set(read_table(str(out))["orientation_source"])
    assert _present(mods, ("torch", "matplotlib", "gamd")) == []
    assert sorted(m for m in mods if m == "scipy" or m.startswith("scipy.")) == []
    # negative control: the check sees torch where it is imported
    assert "torch" in _modules_after("import torch")


def test_what_the_command_imports_before_forking_holds_no_scipy() -> None:
    code = "import blurtrack.cli.detect, blurtrack.io.session, blurtrack.detect.session.pipeline"
    mods = _modules_after(code)
    assert "blurtrack.detect.lines.endpoints" in mods  # the detector was imported
    assert sorted(m for m in mods if m == "scipy" or m.startswith("scipy.")) == []
    # negative control: the test renderer does import scipy.special
    assert "scipy.special" in _modules_after("import blurtrack.testing.streak_frames")


@pytest.mark.parametrize("n", [0, 1, 7])
def test_split_at_gives_the_views_np_split_gives(n: int) -> None:
    rng = np.random.default_rng(n)
    sizes = rng.integers(0, 5, n)
    flat = rng.normal(size=(int(sizes.sum()), 2))
    cuts = np.cumsum(sizes)[:-1]
    mine, ref = split_at(flat, cuts), np.split(flat, cuts)  # the new path and the old one
    assert len(mine) == len(ref) == max(n, 1)
    start = 0
    for k, (a, b) in enumerate(zip(mine, ref, strict=True)):
        size = int(sizes[k]) if n else 0
        np.testing.assert_array_equal(a, flat[start : start + size])  # rows of piece k
        assert a.shape == b.shape == (size, 2)
        np.testing.assert_array_equal(a, b)
        assert a.base is flat or a.size == 0  # views, not copies
        start += size
