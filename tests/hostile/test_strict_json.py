"""Summaries are strict JSON (no bare NaN), and ``gamd --limit`` must be a positive count."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from blurtrack.io.atomic import write_json_atomic
from blurtrack.testing.mini_session import write_synthetic_session
from gamd.cli import main as gamd_main
from tests.hostile.conftest import debris

REPO = Path(__file__).resolve().parents[2]
#: summary writers outside this change's reach (blurtrack/cli/importers.py is being changed by
#: another developer); each must move to write_json_atomic too


def _strict(text: str) -> object:
    """Parse JSON refusing NaN and infinities, as every strict parser does."""

    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_write_json_atomic_never_writes_nan(tmp_path: Path) -> None:
    path = write_json_atomic(tmp_path / "summary.json", {"a": math.nan, "b": [math.inf, 1.0]})
    assert _strict(path.read_text()) == {"a": None, "b": [None, 1.0]}


def _calls(text: str, name: str) -> list[str]:
    """The full text of every call ``name(...)`` in ``text`` (parentheses balanced)."""
    out = []
    for m in re.finditer(re.escape(name) + r"\(", text):
        depth, i = 0, m.end() - 1
        for i in range(m.end() - 1, len(text)):
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            if depth == 0:
                break
        out.append(text[m.start() : i + 1])
    return out


def test_every_summary_writer_is_strict() -> None:
    """No module writes a summary with a bare json.dumps: they all use write_json_atomic."""
    offenders = []
    for pkg in ("blurtrack", "gamd", "rigs", "calib"):
        for path in sorted((REPO / pkg).rglob("*.py")):
            rel = str(path.relative_to(REPO))
            for call in _calls(path.read_text(), "write_text_atomic"):
                bare = "json.dumps" in call or "to_json" in call
                if "summary" in call and bare:
                    offenders.append(f"{rel}: {' '.join(call.split())[:90]}")
    assert offenders == []
    bare = 'write_text_atomic(out / "summary.json", json.dumps(summary, indent=2))'
    assert any("summary" in c for c in _calls(bare, "write_text_atomic"))  # the scan finds one


@pytest.mark.parametrize("limit", ["-1", "0"])
def test_gamd_eval_refuses_a_non_positive_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture, limit: str
) -> None:
    out = tmp_path / "ev"
    argv = ["eval", "--data", str(tmp_path / "none"), "--out", str(out), "--limit", limit]
    assert gamd_main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--limit must be a positive number" in err, err
    assert not out.exists() and debris(tmp_path) == []


def test_gamd_deblur_refuses_a_non_positive_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    write_synthetic_session(tmp_path / "S", n_frames=2, resolution=(64, 48), grid=(2, 2))
    out = tmp_path / "d"
    assert gamd_main(["deblur", str(tmp_path / "S"), "--out", str(out), "--limit", "-3"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "got -3" in err, err
    assert not out.exists() and debris(tmp_path) == []
