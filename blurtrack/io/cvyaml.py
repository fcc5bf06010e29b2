"""Reading OpenCV ``FileStorage`` YAML (EuRoC ``sensor.yaml``, OpenVINS chain files) safely.

OpenCV writes a ``%YAML:1.0`` directive that PyYAML rejects, and may tag matrices
``!!opencv-matrix``. The directive line is dropped and the text parsed with a ``SafeLoader``
that knows only that one extra tag (a mapping ``rows, cols, dt, data``, returned as a dict).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import yaml

from blurtrack.errors import ConfigError

#: Largest YAML file read (bytes).
MAX_YAML_BYTES = 16 * 1024**2


class _CvSafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` plus OpenCV's ``!!opencv-matrix`` tag (a plain mapping)."""


def _matrix(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict[str, Any]:
    return cast("dict[str, Any]", loader.construct_mapping(node, deep=True))


_CvSafeLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _matrix)


def strip_directive(text: str) -> str:
    """``text`` without a leading ``%YAML:1.0`` (OpenCV's form, not YAML's ``%YAML 1.x``)."""
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML:"):
        lines = lines[1:]
    return "\n".join(lines) + "\n"


def load_cv_yaml_text(text: str, source: str) -> Any:
    try:
        return yaml.load(strip_directive(text), Loader=_CvSafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise ConfigError(f"{source}: not valid YAML{where}") from None


def read_cv_yaml(path: str | Path, what: str) -> Any:
    """Parse a YAML file that may be OpenCV FileStorage YAML; one-line errors."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} not found: {p}")
    if p.stat().st_size > MAX_YAML_BYTES:
        raise ConfigError(f"{what} {p} is larger than {MAX_YAML_BYTES} bytes")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{what} {p} is not UTF-8 text") from None
    return load_cv_yaml_text(text, f"{what} {p}")


def matrix(value: Any, rows: int, cols: int, source: str) -> list[list[float]]:
    """A ``rows x cols`` matrix from a nested list or an OpenCV/EuRoC ``{rows, cols, data}``."""
    import numpy as np

    try:
        if isinstance(value, dict):
            if int(value.get("rows", rows)) != rows or int(value.get("cols", cols)) != cols:
                raise ConfigError(f"{source}: expected a {rows}x{cols} matrix")
            value = value["data"]
        M = np.array(value, dtype=float).reshape(rows, cols)
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"{source}: expected a {rows}x{cols} matrix of numbers") from None
    if not np.all(np.isfinite(M)):
        raise ConfigError(f"{source}: matrix has non-finite entries")
    return M.tolist()
