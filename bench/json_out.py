"""The end of a benchmark script: its JSON document printed and, with ``--out``, written."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def emit(result: Any, out: Path | None, indent: int = 1) -> int:
    """Print ``result`` as JSON, also write it to ``out`` when given; returns exit status 0."""
    text = json.dumps(result, indent=indent)
    print(text)
    if out:
        out.write_text(text + "\n")
    return 0
