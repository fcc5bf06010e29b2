"""The import contract of docs/conventions.md, checked on every import statement of the tree.

| package   | may import (first party)      | must not import (third party)       |
| blurtrack | blurtrack (its cli/ may reach the others lazily) | casadi, torch             |
| rigs      | blurtrack, rigs               | casadi, torch                       |
| calib     | blurtrack, calib              | torch                               |
| gamd      | blurtrack, gamd               | casadi                              |

Every ``import`` and ``from ... import`` is found with ``ast``, including the lazy ones inside
functions, so a violation cannot hide behind a local import. A second test imports the session
I/O in a fresh interpreter and checks that neither torch nor CasADi gets loaded (they are
optional extras).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FIRST_PARTY = ("blurtrack", "rigs", "calib", "gamd")

#: package -> (first-party packages it may import, third-party packages it must not import)
CONTRACT: dict[str, tuple[set[str], set[str]]] = {
    "blurtrack": ({"blurtrack"}, {"casadi", "torch"}),
    "rigs": ({"blurtrack", "rigs"}, {"casadi", "torch"}),
    "calib": ({"blurtrack", "calib"}, {"torch"}),
    "gamd": ({"blurtrack", "gamd"}, {"casadi"}),
}
#: The blurtrack CLI dispatches to the other packages' command modules (lazily).
CLI_DISPATCH = {"blurtrack", "rigs", "calib", "gamd"}


def imported_tops(path: Path) -> set[str]:
    """Top-level names of every module imported anywhere in one file (absolute imports)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    tops: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            tops.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            tops.add(node.module.split(".")[0])
    return tops


def violations(package: str) -> list[str]:
    allowed, banned = CONTRACT[package]
    found = []
    for path in sorted((REPO / package).rglob("*.py")):
        rel = path.relative_to(REPO)
        may = CLI_DISPATCH if rel.parts[:2] == ("blurtrack", "cli") else allowed
        for top in sorted(imported_tops(path)):
            if (top in FIRST_PARTY and top not in may) or top in banned:
                found.append(f"{rel} imports {top}")
    return found


@pytest.mark.parametrize("package", sorted(CONTRACT))
def test_package_imports_only_what_the_layering_allows(package: str) -> None:
    assert violations(package) == []


def test_the_checker_sees_lazy_imports(tmp_path: Path) -> None:
    # Negative control: an import hidden in a function body is still found.
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from calib.fit import calibrate\n    import torch.nn\n")
    assert imported_tops(f) == {"calib", "torch"}


def test_session_io_and_cli_parser_load_neither_torch_nor_casadi() -> None:
    code = (
        "import sys, blurtrack.io.session, blurtrack.io.calibration, blurtrack.cli; "
        "blurtrack.cli.build_parser(); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'casadi'}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True
    )
    assert out.stdout.strip() == "[]"


def test_a_missing_optional_package_is_one_line_advice() -> None:
    from blurtrack.cli import missing_extra_message

    assert "blurtrack[gamd]" in (missing_extra_message(ModuleNotFoundError(name="torch.nn")) or "")
    assert missing_extra_message(ModuleNotFoundError(name="numpy")) is None


def test_one_opencv_build_the_contrib_one() -> None:
    from importlib.metadata import distributions

    import cv2

    names = {(d.metadata["Name"] or "").lower() for d in distributions()}
    assert {n for n in names if n.startswith("opencv")} == {"opencv-contrib-python-headless"}
    assert hasattr(cv2, "ximgproc")  # thinning for skeletons, from the contrib modules


def test_the_recording_stack_does_not_know_the_simulator() -> None:
    # The recorder, clock sync, log and conversion see devices only through ImuSource and
    # CameraSource; the virtual devices and the simulator register behind the URL schemes.
    fake = {"rigs.fake_imu", "rigs.fake_camera", "rigs.sim"}
    for name in ("recorder", "timesync", "reclog", "convert"):
        tree = ast.parse((REPO / "rigs" / f"{name}.py").read_text(encoding="utf-8"))
        mods = {
            n.module
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom) and n.module is not None
        } | {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        assert not {m for m in mods if any(m == f or m.startswith(f + ".") for f in fake)}, name


def module_graph(packages: tuple[str, ...]) -> dict[str, set[str]]:
    """First-party module -> first-party modules it imports anywhere in its file (imports
    inside functions included; those under ``if TYPE_CHECKING:`` left out: they never run)."""
    files = {}
    for pkg in packages:
        for p in sorted((REPO / pkg).rglob("*.py")):
            name = ".".join(p.relative_to(REPO).with_suffix("").parts)
            files[name.removesuffix(".__init__")] = p
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        typing_only = {
            id(n)
            for node in ast.walk(tree)
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for n in ast.walk(node)
        }
        deps = set()
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    deps.add(sub if sub in files else node.module)
            elif isinstance(node, ast.Import):
                deps.update(alias.name for alias in node.names)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (import cycles).

    >>> cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}})
    [['a', 'b']]
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_function_level_imports_included() -> None:
    """docs/conventions.md: modules import only downward; a lazy import inside a function
    keeps start-up fast but must not close a loop."""
    assert cycles(module_graph(FIRST_PARTY)) == []
    # negative control: the checker sees a loop closed by a function-level import
    assert cycles({"calib.a": {"calib.b"}, "calib.b": {"calib.a"}}) == [["calib.a", "calib.b"]]


def private_imports(path: Path) -> list[str]:
    """``module._name`` for every private name ``path`` imports from a first-party module
    (lazy imports included): a helper used across modules is public and named."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] not in FIRST_PARTY:
                continue
            found += [
                f"{node.module}.{a.name}"
                for a in node.names
                if a.name.startswith("_") and not a.name.startswith("__")
            ]
    return found


def test_no_private_name_is_imported_across_library_modules(tmp_path: Path) -> None:
    """docs/conventions.md: what another module needs is public (tests may reach inside)."""
    hits = {
        str(p.relative_to(REPO)): private_imports(p)
        for pkg in FIRST_PARTY
        for p in sorted((REPO / pkg).rglob("*.py"))
    }
    assert {k: v for k, v in hits.items() if v} == {}
    # negative control: a lazy import of a private helper is seen
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from calib.fitcore import _helper\n    return _helper\n")
    assert private_imports(bad) == ["calib.fitcore._helper"]
