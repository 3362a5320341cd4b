"""Every public function of ddgjax documents its parameters and what it returns (Google style: `Args:`, `Returns:`).

The public functions are those the API reference documents (`docs/hooks.py`'s `public_names`: each object where it is
defined). A function with parameters needs an `Args:` section naming each of them (`self`, `*args` / `**kwargs` and
positional-only math letters included), and every function a `Returns:` section (a generator `Yields:`). The rule is
held to planted docstrings, so emptying it is caught.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import pathlib
import re

import pytest

_SPEC = importlib.util.spec_from_file_location("docs_hooks", pathlib.Path(__file__).resolve().parents[1] / "docs" / "hooks.py")
hooks = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(hooks)


def _public_functions() -> dict[str, object]:
    found = {}
    for entries in hooks.public_names().values():
        for entry in entries:
            path = entry.partition("#")[2]
            module, _, name = path.rpartition(".")
            if not path or not module:
                continue
            value = getattr(importlib.import_module(module), name, None)
            if inspect.isfunction(value):
                found[path] = value
    return dict(sorted(found.items()))


def missing_sections(function) -> list[str]:
    """What `function`'s docstring lacks: `Args:`, a parameter of it by name, `Returns:`."""
    doc = inspect.getdoc(function) or ""
    missing = []
    parameters = list(inspect.signature(function).parameters)
    if parameters:
        args = re.search(r"^Args:\n((?:[ \t]+.*\n?|\n)*)", doc, flags=re.MULTILINE)
        if args is None:
            missing.append("Args:")
        else:
            named = set(re.findall(r"^[ \t]+\*{0,2}(\w+)(?:, \*{0,2}\w+)*[ \t]*(?:\(.*?\))?:", args.group(1), flags=re.MULTILINE))
            named |= {
                name
                for group in re.findall(r"^[ \t]+((?:\*{0,2}\w+, )+\*{0,2}\w+)[ \t]*:", args.group(1), flags=re.MULTILINE)
                for name in re.findall(r"\w+", group)
            }
            missing += [name for name in parameters if name not in named]
    if not re.search(r"^(Returns|Yields):", doc, flags=re.MULTILINE):
        missing.append("Returns:")
    return missing


PUBLIC = _public_functions()


def test_there_are_public_functions():
    assert len(PUBLIC) > 250


@pytest.mark.parametrize("path", list(PUBLIC))
def test_public_function_documents_its_parameters_and_result(path):
    missing = missing_sections(PUBLIC[path])
    assert not missing, f"{path}: its docstring lacks {missing}"


def test_the_rule_catches_missing_sections():
    def documented(mesh, u, /, *, mass="voronoi"):
        """One line.

        Args:
            mesh: the mesh.
            u, mass: a value and the mass matrix.

        Returns:
            Something.
        """

    def undocumented(mesh, *, throw=True):
        """One line.

        Args:
            mesh: the mesh.
        """

    assert missing_sections(documented) == []
    assert missing_sections(undocumented) == ["throw", "Returns:"]
