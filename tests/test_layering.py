"""The package's plan, enforced (DESIGN.md, layout): one-way layers, no private import across packages, no circle.

The layers contract lives in pyproject.toml (`[tool.importlinter]`) and is checked here by
import-linter itself, as `lint-imports` checks it in CI; the two rules import-linter has no contract
for are checked on the same static import graph (grimp's, import-linter's own).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _lint_imports(directory: Path) -> subprocess.CompletedProcess:
    """`lint-imports` (import-linter's command, installed beside this Python) run on the package under `directory`."""
    command = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or "lint-imports"
    environment = {"PYTHONPATH": str(directory), "PATH": str(Path(sys.executable).parent)}
    return subprocess.run([command, "--no-cache"], cwd=directory, env=environment, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("ddgjax", cache_dir=None)


def _package(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_the_layers_contract_holds():
    run = _lint_imports(ROOT)
    assert run.returncode == 0, run.stdout + run.stderr


def test_no_package_imports_a_private_module_of_another(graph):
    # ddgjax.x may import ddgjax.y and ddgjax.y.internal, never ddgjax.y._z; the floor modules (ddgjax._errors, ...) are shared.
    crossings = [
        f"{importer} -> {imported}"
        for importer in graph.modules
        for imported in graph.find_modules_directly_imported_by(importer)
        if _package(importer) != _package(imported) and any(part.startswith("_") for part in imported.split(".")[2:])
    ]
    assert not crossings, "import the package's public API or its `internal` module instead:\n" + "\n".join(sorted(crossings))


def test_the_module_import_graph_has_no_circle(graph):
    edges = nx.DiGraph(
        (importer, imported) for importer in graph.modules for imported in graph.find_modules_directly_imported_by(importer)
    )
    circle = next(iter(nx.simple_cycles(edges)), None)
    assert circle is None, f"modules import each other in a circle: {' -> '.join([*circle, circle[0]])}"


def test_no_name_is_resolved_by_importlib_inside_the_package():
    # A name found by `importlib` is invisible to the graph the checks above read (the old `ddgjax.internal` registry).
    users = [
        str(path.relative_to(ROOT))
        for path in (ROOT / "ddgjax").rglob("*.py")
        # the root __init__ re-exports the public API lazily (PEP 562; DESIGN.md), the one sanctioned use
        if "importlib.import_module(" in path.read_text() and path != ROOT / "ddgjax" / "__init__.py"
    ]
    assert not users, f"import statically (a package's `internal` module): {users}"


def test_the_checks_see_a_planted_upward_import(tmp_path):
    # The contract is not vacuous: a copy of the package in which the bottom layer imports a domain package breaks it.
    shutil.copytree(ROOT / "ddgjax", tmp_path / "ddgjax", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    errors = tmp_path / "ddgjax" / "_errors.py"
    errors.write_text(errors.read_text() + "\nfrom .mesh import Mesh  # planted\n")
    run = _lint_imports(tmp_path)
    assert run.returncode != 0 and "ddgjax._errors -> ddgjax.mesh" in run.stdout, run.stdout + run.stderr
