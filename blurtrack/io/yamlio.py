"""Safe YAML reading and atomic writing for untrusted parameter files."""

from __future__ import annotations

import re
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
            return yaml.load(f, Loader=Loader)
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


def parse_yaml(text: str) -> Any:
    """``text`` parsed as :func:`read_yaml` parses a file (the safe loader, exponents read as
    numbers); YAML errors propagate (:class:`yaml.YAMLError`)."""
    return yaml.load(text, Loader=Loader)


def dump_yaml(data: Any, **options: Any) -> str:
    """``data`` as YAML text that :func:`parse_yaml` reads back to the same values (the safe
    dumper; a string such as ``'3e6'`` is quoted). ``options``: those of ``yaml.dump``."""
    return yaml.dump(data, Dumper=Dumper, **options)


def write_yaml(path: str | Path, data: Any) -> None:
    """Write ``data`` as YAML atomically (temporary file, then rename)."""
    text = dump_yaml(data, sort_keys=False, default_flow_style=None, width=100)
    write_text_atomic(path, text)


def write_text_atomic(path: str | Path, text: str) -> None:
    """UTF-8 ``text`` to ``path`` through the one atomic writer (:mod:`blurtrack.io.atomic`)."""
    atomic.write_text_atomic(path, text)


#: A number written with an exponent and no dot or no exponent sign (``3e6``, ``1e-2``,
#: ``1.5e6``): YAML 1.2 and every other reader take it for a number, PyYAML's YAML 1.1
#: resolver for text, so that ``min_threshold: 1e-2`` would be refused as "not a number".
EXPONENT_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$")
_FLOAT_TAG = "tag:yaml.org,2002:float"


class Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """The safe loader (the C one where PyYAML has it: faster for big truth files) that also
    reads :data:`EXPONENT_FLOAT` as numbers."""


class Dumper(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):  # type: ignore[misc]
    """The safe dumper that quotes strings :class:`Loader` would read as numbers."""


Loader.add_implicit_resolver(_FLOAT_TAG, EXPONENT_FLOAT, list("-+0123456789."))
Dumper.add_implicit_resolver(_FLOAT_TAG, EXPONENT_FLOAT, list("-+0123456789."))
