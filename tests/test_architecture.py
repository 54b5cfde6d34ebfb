"""The stage boundaries of docs/architecture.md, checked the way Python actually loads them.

ruff's banned-api rule (TID251) sees direct imports only; these tests import each package in
a fresh interpreter, so an indirect import (a numpy-only module importing one that imports
pydantic) is caught too.
"""

from __future__ import annotations

import pkgutil
import re
import subprocess
import sys
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
    "sensaov_cli.spec.model",
)
MAX_LINES = 400


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


def test_no_module_is_over_the_size_limit() -> None:
    sizes = {
        str(path.relative_to(REPO)): len(path.read_text().splitlines())
        for path in PACKAGE.rglob("*.py")
    }
    assert sizes, "no modules found"
    assert {path: n for path, n in sizes.items() if n > MAX_LINES} == {}


def test_every_stage_package_exists() -> None:
    stages = {m.name for m in pkgutil.iter_modules(sensaov_cli.__path__) if m.ispkg}
    assert stages == {"cli", "spec", "render", "buffer", "views", "outputs"}


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
