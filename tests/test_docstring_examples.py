"""Every main entry point shows a short example in its docstring, and every example runs as written (doctest).

`ENTRY_POINTS` is one list, kept in `docs/check_site.py`, which also checks that each entry's page on the built
site shows its Examples section. The fast tests check that each docstring has a Google-style `Examples:` section
with at least one `>>>` line (and that the check itself fails on a docstring without one); the slow tests run each
entry's examples with `doctest` (one test per entry point: compiling the kernels takes seconds), in the namespace of
the entry's package plus `ddgjax`, `jax`, `jnp` and `np`, with float64 on as the package docstring asks of
geometry work (each example imports what it uses, so a reader can paste it).
"""

from __future__ import annotations

import doctest
import importlib
import importlib.util
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"
OPTIONS = doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS


def _check_site():
    spec = importlib.util.spec_from_file_location("docs_check_site", DOCS / "check_site.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ENTRY_POINTS: tuple[str, ...] = _check_site().ENTRY_POINTS

_SECTION = re.compile(r"^(?P<indent>[ \t]*)Examples:[ \t]*$", flags=re.MULTILINE)


def resolve(name: str):
    """`(package, object)` of a dotted name `ddgjax.<package>.<name>`."""
    package_name, _, attribute = name.rpartition(".")
    package = importlib.import_module(package_name)
    return package, getattr(package, attribute)


def examples_problem(docstring: str | None) -> str | None:
    """What is missing from a docstring's Google-style `Examples:` section (None when it has one with a `>>>` line)."""
    match = _SECTION.search(docstring or "")
    if match is None:
        return "no 'Examples:' section"
    for line in docstring[match.end() :].splitlines()[1:]:
        if line.strip() and len(line) - len(line.lstrip()) <= len(match["indent"]):
            break  # the section ended: a line no more indented than its title
        if line.lstrip().startswith(">>>"):
            return None
    return "an 'Examples:' section without a '>>>' example"


def entry_doctest(name: str) -> doctest.DocTest:
    """The doctest of one entry point's own docstring (not its members'), in its package's namespace."""
    package, obj = resolve(name)
    globs = {**vars(package), "ddgjax": ddgjax, "jax": jax, "jnp": jnp, "np": np}
    tests = doctest.DocTestFinder(recurse=False).find(obj, name, module=False, globs=globs)
    assert len(tests) == 1 and tests[0].examples, f"{name}: no doctest found in its docstring"
    return tests[0]


def test_entry_points_are_public_and_listed_once():
    assert len(ENTRY_POINTS) >= 40 and len(set(ENTRY_POINTS)) == len(ENTRY_POINTS)
    for name in ENTRY_POINTS:
        assert name.startswith("ddgjax.") and name.count(".") == 2, name
        assert not name.rpartition(".")[2].startswith("_"), name
        resolve(name)  # raises if the name is gone


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_entry_point_docstring_has_an_examples_section(name):
    problem = examples_problem(resolve(name)[1].__doc__)
    assert problem is None, f"{name}: {problem}; add a short runnable example (tests/test_docstring_examples.py)"


def test_the_examples_check_fails_on_docstrings_without_examples():
    def planted(x):
        """Twice `x`.

        Args:
            x: a number; `>>> x` here is not an example.

        Returns:
            `2 x`.
        """
        return 2 * x

    assert examples_problem(planted.__doc__) == "no 'Examples:' section"
    assert examples_problem(None) == "no 'Examples:' section"
    prose_only = "Twice `x`.\n\n    Examples:\n        Call it with a number.\n\n    Returns:\n        >>> not here\n"
    assert examples_problem(prose_only) == "an 'Examples:' section without a '>>>' example"
    assert examples_problem("Twice `x`.\n\n    Examples:\n        >>> 2 * 3\n        6\n") is None


@pytest.mark.slow
@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_entry_point_examples_run(name):
    """Run the entry's examples; a failing one fails with doctest's report (the example, expected and got)."""
    test = entry_doctest(name)
    report: list[str] = []
    x64 = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        result = doctest.DocTestRunner(optionflags=OPTIONS).run(test, out=report.append)
    finally:
        jax.config.update("jax_enable_x64", x64)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed:\n{''.join(report)}"
