"""Test configuration: float64 everywhere, quick XLA compilation, and helpers to locate `../shared`."""

from __future__ import annotations

import os
import pathlib

# The suite checks values, not speed, and compiles hundreds of small programs: XLA's LLVM optimisation
# passes are most of each compilation (the suite runs ~25% faster without them; results agree to
# round-off). Set before the backend starts; inherited by the CLI and notebook subprocesses.
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true")

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
MESHES = SHARED / "meshes"
EXERCISES = SHARED / "reference" / "ddg-exercises"


def read_ddg_reference(name: str) -> dict:
    """`{tag: (rows, numbers) array}` of a DDG exercises reference file (`../shared/reference/ddg-exercises`,
    FORMAT.md: one record a line, a tag then numbers); skips the test when `../shared` is absent."""
    records: dict[str, list] = {}
    for line in shared_path("reference", "ddg-exercises", name).read_text().splitlines():
        tag, *numbers = line.split()
        records.setdefault(tag, []).append([float(x) for x in numbers])
    return {tag: np.array(rows) for tag, rows in records.items()}


def shared_path(*parts: str) -> pathlib.Path:
    """Path inside `../shared`; skips the calling test with a clear reason when it is absent."""
    path = SHARED.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared test data not found: {path} (tests that read ../shared need it beside the repo)")
    return path


@pytest.fixture
def without_type_checker():
    """Turn off the suite's run-time type checker (jaxtyping + beartype) for one test: what a user sees,
    for tests of the library's own `DDGInputError` messages on arguments of the wrong type."""
    import jaxtyping

    jaxtyping.config.update("jaxtyping_disable", True)
    yield
    jaxtyping.config.update("jaxtyping_disable", False)


@pytest.fixture(autouse=True)
def _no_compilation_cache_in_the_home_directory(monkeypatch):
    """CLI tests must not write JAX's persistent cache under the user's home (tests that test the
    cache point it at a temporary directory themselves)."""
    monkeypatch.setenv("DDGJAX_COMPILATION_CACHE", "0")


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """`ddgjax.cli.main(argv)` with its exit status (also from SystemExit), stdout and stderr.

    Without the persistent compilation cache: a test writes nothing to the user's cache directory
    (tests/test_cli.py tests the cache).
    """
    import contextlib
    import io
    import os
    from unittest import mock

    from ddgjax._cli import CACHE_VARIABLE
    from ddgjax.cli import main

    out, err = io.StringIO(), io.StringIO()
    with mock.patch.dict(os.environ, {CACHE_VARIABLE: "0"}), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as exit_:
            status = exit_.code
    return status, out.getvalue(), err.getvalue()
