"""The repository's benchmark scripts (``bench/*.py``, not a package) loaded as modules, for
tests of their measures."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

#: ``bench/`` beside the package (the repository's checkout).
BENCH_DIR = Path(__file__).resolve().parents[2] / "bench"


def load_bench_script(name: str) -> ModuleType:
    """``bench/<name>.py`` executed as the module ``name``; ``bench/`` goes on ``sys.path``
    first, so that its sibling modules import as when the script runs.

    Raises:
        FileNotFoundError: no such script (e.g. an installed package without its checkout).
    """
    path = BENCH_DIR / f"{name}.py"
    if not path.is_file():
        raise FileNotFoundError(f"no benchmark script {path}")
    if str(BENCH_DIR) not in sys.path:
        sys.path.insert(0, str(BENCH_DIR))
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
