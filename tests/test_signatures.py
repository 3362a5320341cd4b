"""The vocabulary as a test: every public signature of every package against ddgjax/_vocabulary.py.

Fails on a synonym of a term, an option that can be passed by position, a math letter that can be
passed by keyword, or a default that differs from its namesakes' (each exception is listed, with its
reason, in the vocabulary module). docs/conventions.md's table must be the one the module generates.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import ddgjax
from ddgjax import _vocabulary as vocabulary

ROOT = Path(__file__).resolve().parents[1]


def public_callables() -> Iterator[tuple[str, Callable]]:
    """`(qualified name, function)` for every public function of every package, and every public method of their classes."""
    modules = [ddgjax] + [importlib.import_module(f"ddgjax.{name}") for name in ddgjax._SUBPACKAGES]
    seen = set()
    for module in modules:
        for name in sorted(getattr(module, "__all__", None) or dir(module)):
            if name.startswith("_"):
                continue
            value = getattr(module, name)
            if inspect.ismodule(value) or id(value) in seen:
                continue
            seen.add(id(value))
            qualified = f"{module.__name__}.{name}"
            if inspect.isclass(value):
                if not value.__module__.startswith("ddgjax"):
                    continue
                for attribute, member in vars(value).items():
                    member = member.__func__ if isinstance(member, (classmethod, staticmethod)) else member
                    if not attribute.startswith("_") and inspect.isfunction(member):
                        yield f"{qualified}.{attribute}", member
            elif callable(value) and getattr(value, "__module__", "").startswith("ddgjax"):
                yield qualified, value


def parameters(function: Callable) -> list[inspect.Parameter]:
    """The parameters a caller passes (no `self` / `cls`, no `*args` / `**kwargs`)."""
    listed = list(inspect.signature(function).parameters.values())
    if listed and listed[0].name in ("self", "cls"):
        listed = listed[1:]
    return [parameter for parameter in listed if parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)]


def violations(functions) -> list[str]:
    """What the vocabulary refuses in `functions` (`(qualified name, function)` pairs), one line each."""
    synonyms = {synonym: term for term in vocabulary.TERMS for synonym in term.synonyms}
    defaults = {
        name: term.default for term in vocabulary.TERMS for name in term.parameters if term.default is not vocabulary.PER_FUNCTION
    }
    found = []
    for qualified, function in functions:
        for parameter in parameters(function):
            name = parameter.name
            if name in synonyms:
                found.append(f"{qualified}: `{name}` is a synonym of {synonyms[name].spelled} ({synonyms[name].concept})")
            has_default = parameter.default is not parameter.empty
            if (
                has_default
                and parameter.kind == parameter.POSITIONAL_OR_KEYWORD
                and qualified not in vocabulary.POSITIONAL_WITH_DEFAULT
            ):
                found.append(f"{qualified}: the option `{name}` can be passed by position; make it keyword-only")
            if len(name) == 1 and name not in vocabulary.LETTERS_BY_KEYWORD and parameter.kind != parameter.POSITIONAL_ONLY:
                found.append(f"{qualified}: the math letter `{name}` can be passed by keyword; make it positional-only (`/`)")
            excepted = f"{qualified}:{name}" in vocabulary.DEFAULT_EXCEPTIONS
            if has_default and name in defaults and not excepted and not _same(parameter.default, defaults[name]):
                found.append(f"{qualified}: `{name}={parameter.default!r}` where the vocabulary's default is {defaults[name]!r}")
    return found


def _same(a, b) -> bool:
    return type(a) is type(b) and a == b if not isinstance(a, float) else isinstance(b, float) and a == b


def test_every_public_signature_speaks_the_vocabulary():
    functions = list(public_callables())
    assert len(functions) > 250, "the walk over the public API found too little: is a package missing?"
    found = violations(functions)
    assert not found, "\n".join(found)


def test_the_walk_reaches_every_kind_of_public_callable():
    names = {name for name, _ in public_callables()}
    assert {
        "ddgjax.solve.linear_solve",
        "ddgjax.Mesh.from_arrays",
        "ddgjax.geodesics.heat_distance",
        "ddgjax.volume.cotan_laplacian",
    } <= names


def _planted(seed: int = 0, *, throw: bool = False, mass: str = "barycentric", solver="auto", L=None):
    """A function that breaks each rule once."""


@pytest.mark.parametrize(
    "expected",
    [
        "`seed` is a synonym of `key=`",
        "the option `seed` can be passed by position",
        "`throw=False` where the vocabulary's default is True",
        "`mass='barycentric'` where the vocabulary's default is 'voronoi'",
        "the math letter `L` can be passed by keyword",
    ],
)
def test_the_checker_catches_a_planted_break(expected):
    found = violations([("planted", _planted)])
    assert any(expected in line for line in found), found
    assert not any("solver" in line for line in found)  # the term's default, as written: nothing to report
    assert len(found) == 5


def test_every_term_default_is_one_its_functions_use():
    # A term's default that no function uses would check nothing.
    used = {(parameter.name, repr(parameter.default)) for _, function in public_callables() for parameter in parameters(function)}
    for term in vocabulary.TERMS:
        if term.default is not vocabulary.PER_FUNCTION:
            assert any((name, repr(term.default)) in used for name in term.parameters), term.concept


def test_every_exception_names_a_public_function_that_needs_it():
    names = {name for name, _ in public_callables()}
    for entry in [*vocabulary.POSITIONAL_WITH_DEFAULT, *(key.split(":")[0] for key in vocabulary.DEFAULT_EXCEPTIONS)]:
        assert entry in names, f"{entry}: listed as an exception in ddgjax/_vocabulary.py but not a public function"


def test_the_conventions_page_shows_the_vocabulary_table():
    page = (ROOT / "docs" / "conventions.md").read_text()
    assert vocabulary.with_table(page) == page, "docs/conventions.md is stale: run `python -m ddgjax._vocabulary`"


def _public_classes():
    modules = [ddgjax] + [importlib.import_module(f"ddgjax.{name}") for name in ddgjax._SUBPACKAGES]
    for module in modules:
        for name in sorted(getattr(module, "__all__", None) or dir(module)):
            value = getattr(module, name)
            if inspect.isclass(value) and value.__module__.startswith("ddgjax") and not name.startswith("_"):
                yield f"{module.__name__}.{name}", value


#: Classes with an outcome that are not records of an answer, and why.
NOT_RECORDS = {"ddgjax.solve.Factorization": "a kept solver state (lineax's solver state): its solves return the records"}


def test_every_record_has_value_result_and_stats():
    # One record shape (lineax / optimistix): whatever carries an outcome is a ddgjax.Record, whose three names
    # equinox checks are provided (as fields or properties) when the class is defined.
    records = {
        name: cls
        for name, cls in _public_classes()
        if "result" in dir(cls) or any(f == "result" for f in getattr(cls, "__dataclass_fields__", {}))
    }
    assert {"ddgjax.solve.LinearSolution", "ddgjax.matching.MatchResult", "ddgjax.curves.CurveFlowResult"} <= set(records)
    for name, cls in records.items():
        if name not in NOT_RECORDS:
            assert issubclass(cls, ddgjax.Record), (
                f"{name}: a record with `result` must subclass ddgjax.Record (value, result, stats)"
            )
            assert isinstance(inspect.getattr_static(cls, "stats", None), property) or "stats" in cls.__dataclass_fields__, name


def test_a_record_gives_its_states_by_methods():
    # `.mesh(i)` / `.curve(i)` are methods on every record (a state by index, or the final one), never properties.
    for name, cls in _public_classes():
        for accessor in ("mesh", "curve", "tet_mesh"):
            assert not isinstance(inspect.getattr_static(cls, accessor, None), property), (
                f"{name}.{accessor} is a property; make it a method"
            )
