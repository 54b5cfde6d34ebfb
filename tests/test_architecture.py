"""The stage boundaries of docs/architecture.md, checked the way Python actually loads them.

ruff's banned-api rule (TID251, one ruff.toml per package) sees direct imports only; these
tests import each package in a fresh interpreter, so an indirect import (a numpy-only module
importing one that imports pydantic) is caught too, and walk every import statement of the
package, lazy ones inside functions included, to refuse an import cycle.
"""

from __future__ import annotations

import ast
import pkgutil
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

import sensaov_cli

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "sensaov_cli"
HEAVY = ("mitsuba", "drjit", "pydantic", "yaml", "click", "matplotlib")
# Packages (and top-level modules) that a buffer reader, a compositor script or a farm's
# post-processing step may import on a machine without the renderer or the CLI.
NUMPY_ONLY = (
    "sensaov_cli.buffer",
    "sensaov_cli.views",
    "sensaov_cli.outputs",
    "sensaov_cli.errors",
    "sensaov_cli.vocabulary",
    "sensaov_cli.progress",
    "sensaov_cli.interrupts",
    "sensaov_cli.limits",
    "sensaov_cli.job.spec",
    "sensaov_cli.scene",  # scene preparation is pure XML: validate loads no renderer
)
# At the root: the package face, the entry point and at most five cross-cutting modules.
ROOT_MODULES = {"__init__", "__main__", "errors", "progress", "interrupts", "vocabulary", "limits"}


def modules_of(name: str) -> list[str]:
    """``name`` and, for a package, every module in it."""
    path = PACKAGE.joinpath(*name.split(".")[1:])
    if not path.is_dir():
        return [name]
    return [name] + [f"{name}.{m.name}" for m in pkgutil.iter_modules([str(path)])]


def loaded_after_import(modules: list[str]) -> set[str]:
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}: importlib.import_module(name)\n"
        f"print(' '.join(sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r})))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True
    )
    return set(result.stdout.split())


@pytest.mark.parametrize("package", NUMPY_ONLY)
def test_numpy_only_packages_import_no_heavy_library(package: str) -> None:
    modules = modules_of(package)
    assert modules, package
    assert loaded_after_import(modules) == set(), f"{package} pulls in a heavy library"


def test_the_check_sees_a_heavy_import() -> None:
    """The probe itself works: the CLI package does load click."""
    assert "click" in loaded_after_import(["sensaov_cli.cli"])


def test_cli_help_imports_no_renderer() -> None:
    """--help must stay instant: the commands import the stages inside their functions."""
    assert {"mitsuba", "drjit"} & loaded_after_import(["sensaov_cli.cli"]) == set()


def test_every_stage_package_exists() -> None:
    stages = {m.name for m in pkgutil.iter_modules(sensaov_cli.__path__) if m.ispkg}
    assert stages == {
        "cli",
        "pipeline",
        "live",
        "job",
        "scene",
        "render",
        "buffer",
        "views",
        "outputs",
    }


def test_the_root_holds_only_the_face_and_cross_cutting_modules() -> None:
    modules = {path.stem for path in PACKAGE.glob("*.py")}
    assert modules == ROOT_MODULES
    assert len(ROOT_MODULES - {"__init__", "__main__"}) <= 5


def test_every_command_has_its_wiring_in_pipeline() -> None:
    """cli/<verb>.py is the command's face; pipeline/<verb>.py its wiring (schema needs none,
    and view's is the live/ package)."""
    commands = {p.stem for p in (PACKAGE / "cli").glob("*.py")} - {"__init__", "options"}
    wiring = {p.stem for p in (PACKAGE / "pipeline").glob("*.py")}
    assert commands - {"schema", "view"} <= wiring


def test_no_two_modules_share_a_base_name() -> None:
    """Except a command's face in cli/ and its wiring in pipeline/: from a module's name alone a
    newcomer knows which one it is."""
    names = Counter(
        p.stem for p in PACKAGE.rglob("*.py") if p.stem != "__init__" and p.parent.name != "cli"
    )
    assert [name for name, count in names.items() if count > 1] == []


# --- import cycles --------------------------------------------------------------------------


def import_graph(root: Path, package: str) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, lazy imports inside functions included and
    imports under ``if TYPE_CHECKING:`` left out (they never run). ``from pkg import name``
    counts as importing ``pkg.name`` when that is a module, else ``pkg``."""
    modules = {_module_name(path, root, package): path for path in root.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        skipped = {id(n) for node in ast.walk(tree) if _type_checking(node) for n in ast.walk(node)}
        targets = set()
        for node in ast.walk(tree):
            if id(node) in skipped:
                continue
            if isinstance(node, ast.Import):
                targets |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    targets.add(full if full in modules else node.module)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def _module_name(path: Path, root: Path, package: str) -> str:
    parts = [package, *path.relative_to(root).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking(node: ast.AST) -> bool:
    test = node.test if isinstance(node, ast.If) else None
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected set of two or more modules (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_package_has_no_import_cycle() -> None:
    graph = import_graph(PACKAGE, "sensaov_cli")
    assert len(graph) > 50, "the walk found too few modules"
    assert cycles(graph) == []


def test_the_cycle_walk_sees_a_lazy_cycle_and_skips_type_checking(tmp_path: Path) -> None:
    """The probe itself works: a cycle through an import inside a function is found, one
    through ``if TYPE_CHECKING:`` is not (model/npz was such a lazy cycle)."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "model.py").write_text("def load():\n    from pkg.npz import read\n")
    (pkg / "npz.py").write_text("from pkg.model import load\n")
    (pkg / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pkg.b\n"
    )
    (pkg / "b.py").write_text("from pkg import a\n")
    assert cycles(import_graph(pkg, "pkg")) == [["pkg.model", "pkg.npz"]]


def test_architecture_doc_lists_every_module() -> None:
    doc = (REPO / "docs" / "architecture.md").read_text()
    modules = sorted(str(p.relative_to(REPO)) for p in PACKAGE.rglob("*.py"))
    assert [m for m in modules if f"`{m}`" not in doc] == []


def test_module_paths_named_in_the_docs_exist() -> None:
    texts = [REPO / "README.md", *(REPO / "docs").glob("*.md")]
    named = {
        (text.name, match)
        for text in texts
        for match in re.findall(r"sensaov_cli/[\w/]+\.py", text.read_text())
    }
    assert named, "the docs name no module at all"
    assert sorted((doc, path) for doc, path in named if not (REPO / path).is_file()) == []
