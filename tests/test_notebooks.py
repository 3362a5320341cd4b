"""Execute every notebook in `notebooks/` top to bottom; a cell that raises fails the test.

The kernel is a throw-away kernelspec that runs *this* interpreter (so a `python3` kernelspec of
another environment cannot shadow it), with the repository on `PYTHONPATH` (so the notebooks import
the checked-out `ddgjax` even when it is not pip-installed) and a temporary working directory (so
files the notebooks write land there).
"""

from __future__ import annotations

import os
import pathlib

import pytest

# The slow tier (pyproject.toml): each notebook runs a kernel of its own, end to end.
pytestmark = pytest.mark.slow

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory):
    """Name of a kernelspec that launches `sys.executable -m ipykernel_launcher`."""
    pytest.importorskip("nbclient", reason="nbclient is needed to execute notebooks (pip install -e .[test])")
    kernelspec = pytest.importorskip("ipykernel.kernelspec", reason="ipykernel is needed to run a kernel")
    prefix = tmp_path_factory.mktemp("kernel")
    name = "ddgjax-test-python"
    kernelspec.install(kernel_name=name, prefix=str(prefix))
    patch = pytest.MonkeyPatch()
    patch.setenv(
        "JUPYTER_PATH", os.pathsep.join(filter(None, [str(prefix / "share" / "jupyter"), os.environ.get("JUPYTER_PATH")]))
    )
    patch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    yield name
    patch.undo()


@pytest.mark.skipif(not NOTEBOOKS, reason="no notebooks in notebooks/")
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_name, tmp_path):
    import nbclient
    import nbformat

    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        notebook, kernel_name=kernel_name, timeout=300, resources={"metadata": {"path": str(tmp_path)}}
    )
    # Raises nbclient's CellExecutionError, with the cell and its traceback, on the first failing cell.
    client.execute()
