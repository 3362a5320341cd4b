"""The notebooks in `notebooks/`: committed with outputs made from their code as it reads, and still running.

`notebooks/refresh.py` executes them in place and stores the digest of their code; the fast check
here compares that digest with the code (a notebook edited and not refreshed fails it), and the slow
one executes each notebook again top to bottom (a cell that raises fails it) in a throw-away kernel of
this interpreter, the repository first on `PYTHONPATH` and a temporary working directory. The site
shows the stored outputs, so this is the one run of each notebook in CI.
"""

from __future__ import annotations

import importlib.util
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
_SPEC = importlib.util.spec_from_file_location("notebooks_refresh", REPO / "notebooks" / "refresh.py")
refresh = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(refresh)
NOTEBOOKS = refresh.NOTEBOOKS


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 12, [path.name for path in NOTEBOOKS]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_stored_outputs_come_from_the_code_as_it_reads(path):
    nbformat = pytest.importorskip("nbformat")
    notebook = nbformat.read(path, as_version=4)
    code_cells = [cell for cell in notebook.cells if cell.cell_type == "code" and cell.source.strip()]
    assert refresh.stored_digest(notebook) == refresh.code_digest(notebook), (
        f"{path.name}: its code changed since its outputs were made: python notebooks/refresh.py {path.name}"
    )
    assert all(cell.execution_count is not None for cell in code_cells), f"{path.name}: a code cell without its outputs"


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory):
    pytest.importorskip("nbclient", reason="nbclient is needed to execute notebooks (pip install -e .[test])")
    with refresh.kernel(tmp_path_factory.mktemp("kernel")) as name:
        yield name


@pytest.mark.slow  # each notebook runs a kernel of its own, end to end
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_name, tmp_path):
    import nbformat

    refresh.execute(nbformat.read(path, as_version=4), kernel_name, tmp_path, timeout=300)
