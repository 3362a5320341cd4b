"""Execute the notebooks in place, so they are committed with their outputs (figures where people look first).

`python notebooks/refresh.py` runs every notebook here top to bottom in a fresh kernel of this interpreter
(the checked-out `ddgjax` first on the path, a temporary working directory for the files they write) and
writes it back with its outputs and, in its metadata, the SHA-256 of its code (`code_digest`): the test
suite checks that each stored digest is the digest of the code as it now reads, so a notebook edited
and not refreshed is caught, and executes each notebook once more to check it still runs. The site
shows the stored outputs (mkdocs.yml), so no notebook runs twice in CI. `python notebooks/refresh.py
03_poisson.ipynb` refreshes one.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pathlib
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
NOTEBOOKS = sorted(HERE.glob("*.ipynb"))
KERNEL = "ddgjax-notebooks-python"


def code_digest(notebook) -> str:
    """SHA-256 of the notebook's code cells, in order (what its stored outputs were made from)."""
    code = "\n\x00\n".join(cell.source for cell in notebook.cells if cell.cell_type == "code")
    return hashlib.sha256(code.encode("utf-8")).hexdigest()


def stored_digest(notebook) -> str | None:
    """The digest `refresh` wrote into the notebook's metadata, or None."""
    return notebook.metadata.get("ddgjax", {}).get("code_digest")


@contextlib.contextmanager
def kernel(prefix: pathlib.Path):
    """A kernelspec `KERNEL` that runs this interpreter with the repository first on `PYTHONPATH`."""
    from ipykernel import kernelspec

    kernelspec.install(kernel_name=KERNEL, prefix=str(prefix))
    saved = {name: os.environ.get(name) for name in ("JUPYTER_PATH", "PYTHONPATH")}
    os.environ["JUPYTER_PATH"] = os.pathsep.join(filter(None, [str(prefix / "share" / "jupyter"), saved["JUPYTER_PATH"]]))
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), saved["PYTHONPATH"]]))
    try:
        yield KERNEL
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def execute(notebook, kernel_name: str, workdir: pathlib.Path, timeout: int = 600) -> None:
    """Run every cell in order (nbclient's `CellExecutionError` names the first that raises)."""
    import nbclient

    nbclient.NotebookClient(
        notebook, kernel_name=kernel_name, timeout=timeout, resources={"metadata": {"path": str(workdir)}}
    ).execute()


def refresh(paths: list[pathlib.Path]) -> None:
    import nbformat

    with tempfile.TemporaryDirectory(prefix="ddgjax-notebooks-") as folder, kernel(pathlib.Path(folder)) as name:
        for path in paths:
            notebook = nbformat.read(path, as_version=4)
            workdir = pathlib.Path(folder) / path.stem
            workdir.mkdir()
            execute(notebook, name, workdir)
            notebook.metadata.setdefault("ddgjax", {})["code_digest"] = code_digest(notebook)
            nbformat.write(notebook, path)
            print(f"refreshed {path.name}", flush=True)


if __name__ == "__main__":
    names = sys.argv[1:]
    refresh([HERE / name for name in names] if names else NOTEBOOKS)
