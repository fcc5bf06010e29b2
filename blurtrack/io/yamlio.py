"""Safe YAML reading and atomic writing for untrusted parameter files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from blurtrack.errors import ConfigError
from blurtrack.io import atomic

#: Largest YAML file read (bytes); parameter files are tiny, truth files of long simulations
#: are a few MB.
MAX_YAML_BYTES = 256 * 1024 * 1024


def read_yaml(path: str | Path, what: str = "YAML file") -> Any:
    """``yaml.safe_load`` of ``path`` with one-line errors for missing, huge or invalid files."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} not found: {p}")
    size = p.stat().st_size
    if size > MAX_YAML_BYTES:
        raise ConfigError(f"{what} {p} is {size} bytes, over the {MAX_YAML_BYTES}-byte limit")
    try:
        with p.open("r", encoding="utf-8") as f:
            return yaml.load(f, Loader=_LOADER)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{what} {p} is not valid YAML: {yaml_error_line(exc)}") from None


def yaml_error_line(exc: BaseException) -> str:
    """A YAML parser's error in one line: its problem and where (PyYAML's own message spans
    several lines with a source excerpt and a ``^`` marker, which must not reach stderr)."""
    problem = getattr(exc, "problem", None)
    mark = getattr(exc, "problem_mark", None)
    if problem:
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        return f"{problem}{where}"
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def write_yaml(path: str | Path, data: Any) -> None:
    """Write ``data`` as YAML atomically (temporary file, then rename)."""
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    write_text_atomic(path, text)


def write_text_atomic(path: str | Path, text: str) -> None:
    """UTF-8 ``text`` to ``path`` through the one atomic writer (:mod:`blurtrack.io.atomic`)."""
    atomic.write_text_atomic(path, text)


# The C loader is faster for big truth files; both are the safe loader.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
