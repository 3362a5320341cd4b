"""Every tolerance of the suite looser than 1e-10 says why, in a comment beside it.

Scans tests/*.py with `ast` and `tokenize`: a tolerance is the value of a keyword named `rtol`, `atol`, `tol` (or
`..._tol`, `...tolerance`), of `rel=` / `abs=` in `pytest.approx`, the positional `rtol` / `atol` of
`assert_allclose`, `allclose` and `isclose` (and `rel` / `abs` of `approx`), a parameter default of such a name, and
a value assigned to a name containing `tol`. It is loose when it is a number above 1e-10, or an expression (`1e-8 *
np.abs(expected).max()`) with a literal factor between 1e-10 and 1. A loose tolerance needs a comment on one of its
lines or the line above them, or on the line above, the first or the last line of its statement: what sets its size
(round-off of a solve times a condition number, a discretisation error of O(h^2), finite differences of some step,
an iterative solver's or a peer's tolerance, float32, ...), usually with the error measured. A tolerance used
several times is named once (`differences = dict(eps=1e-5, atol=1e-8, rtol=1e-8)`), its reason beside the name.
The rule itself is held to a planted offender.
"""

from __future__ import annotations

import ast
import io
import tokenize
from collections.abc import Iterator
from pathlib import Path

TESTS = Path(__file__).resolve().parent
BOUND = 1e-10
# the positional tolerances after (actual, desired) / (a, b) / (expected,)
POSITIONAL = {"assert_allclose": (2, 3), "allclose": (2, 3), "isclose": (2, 3), "approx": (1, 2)}


def _is_tolerance_name(name: str | None) -> bool:
    """`rtol`, `atol`, `tol`, `area_tol`, `residual_tolerance`, ..."""
    return bool(name) and (name.endswith("tol") or "tolerance" in name)


def _function_name(call: ast.Call) -> str:
    function = call.func
    return function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", "")


def _numbers(node: ast.AST) -> Iterator[ast.Constant]:
    """The numeric literals of an expression, less the exponents of `**` (`10.0 ** -6` is one number)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
        yield from _numbers(node.left)
        return
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        yield node
        return
    for child in ast.iter_child_nodes(node):
        yield from _numbers(child)


def _value(node: ast.AST) -> float | None:
    """The number a constant expression (`1e-6`, `-1.0`, `2 * 1e-3`, `10.0 ** -6`) stands for; None otherwise."""
    if isinstance(node, ast.Constant):
        return float(node.value) if isinstance(node.value, (int, float)) and not isinstance(node.value, bool) else None
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        inner = _value(node.operand)
        return None if inner is None else (-inner if isinstance(node.op, ast.USub) else inner)
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Mult, ast.Div, ast.Pow, ast.Add, ast.Sub)):
        left, right = _value(node.left), _value(node.right)
        if left is None or right is None:
            return None
        operations = {ast.Mult: float.__mul__, ast.Div: float.__truediv__, ast.Pow: float.__pow__, ast.Add: float.__add__}
        try:
            return operations.get(type(node.op), float.__sub__)(left, right)
        except (ZeroDivisionError, OverflowError):
            return None
    return None


def _loose(node: ast.AST) -> bool:
    value = _value(node)
    if value is not None:
        return value > BOUND
    return any(BOUND < abs(literal.value) < 1 for literal in _numbers(node))


def _tolerances(tree: ast.AST) -> Iterator[tuple[ast.AST, ast.AST]]:
    """`(tolerance expression, its statement)` for every tolerance of a module."""
    statements: dict[ast.AST, ast.stmt] = {}

    def enclose(node: ast.AST, statement: ast.stmt | None) -> None:
        statement = node if isinstance(node, ast.stmt) else statement
        if statement is not None:
            statements[node] = statement
        for child in ast.iter_child_nodes(node):
            enclose(child, statement)

    enclose(tree, None)
    for node in ast.walk(tree):
        owner = statements.get(node, node)
        if isinstance(node, ast.Call):
            name = _function_name(node)
            for keyword in node.keywords:
                if _is_tolerance_name(keyword.arg) or (name == "approx" and keyword.arg in ("rel", "abs")):
                    yield keyword.value, owner
            for index in POSITIONAL.get(name, ()):
                if index < len(node.args) and not isinstance(node.args[index], ast.Starred):
                    yield node.args[index], owner
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            arguments = node.args
            positional = arguments.posonlyargs + arguments.args
            pairs = list(zip(positional[len(positional) - len(arguments.defaults) :], arguments.defaults))
            pairs += [(argument, default) for argument, default in zip(arguments.kwonlyargs, arguments.kw_defaults) if default]
            for argument, default in pairs:
                if _is_tolerance_name(argument.arg):
                    yield default, owner
        elif isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(target, ast.Name) and "tol" in target.id.lower() for target in targets):
                yield node.value, node


def offences(source: str, filename: str = "<test>") -> list[str]:
    """`file:line: tolerance` for every loose tolerance of `source` without a comment that says why."""
    tree = ast.parse(source, filename)
    commented = {
        token.start[0] for token in tokenize.generate_tokens(io.StringIO(source).readline) if token.type == tokenize.COMMENT
    }
    found = []
    for value, statement in _tolerances(tree):
        if not _loose(value):
            continue
        near = range(value.lineno - 1, value.end_lineno + 1)  # its lines and the one above
        around = (statement.lineno - 1, statement.lineno, statement.end_lineno)  # above, first and last of its statement
        if not commented.intersection([*near, *around]):
            found.append(f"{filename}:{value.lineno}: {ast.unparse(value)}")
    return sorted(set(found), key=lambda line: (line.split(":")[0], int(line.split(":")[1])))


def test_every_loose_tolerance_says_why():
    found = [line for path in sorted(TESTS.glob("*.py")) for line in offences(path.read_text(), path.name)]
    assert not found, (
        "a tolerance looser than 1e-10 without a reason: say on its line (or the line above) what sets its size "
        "(the step of the differences, the solver's tolerance, the discretisation error, float32, ..., measured)\n"
        + "\n".join(found)
    )


PLANTED = """
import numpy as np
import pytest


def check(a, b, rtol=1e-6):
    np.testing.assert_allclose(a, b, rtol=1e-6)
    np.testing.assert_allclose(a, b, 1e-5, 0)
    np.testing.assert_allclose(
        a,
        b,
        atol=1e-8 * np.abs(b).max(),
    )
    assert a == pytest.approx(b, rel=2e-3)
    tolerance = 1e-7 if a else 1e-12
    assert np.allclose(a, b, atol=tolerance)
"""

EXCUSED = """
import numpy as np


def check(a, b, rtol=1e-6):  # finite differences of step 1e-6: round-off over the step
    np.testing.assert_allclose(a, b, rtol=1e-6)  # CG to a relative residual of 1e-10, condition ~1e4
    # float32 coordinates
    np.testing.assert_allclose(a, b, 1e-5, 0)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(a, b, atol=1e-14 * max(1.0, np.abs(b).max()))
    # the solve's rounding times its condition number, ~1e-9
    np.testing.assert_allclose(
        a,
        b,
        atol=1e-8,
    )
    np.testing.assert_allclose(
        a,
        b,
        rtol=1e-7,
    )  # finite differences of step 1e-6
"""


def test_the_rule_catches_a_planted_bare_tolerance():
    lines = [int(line.split(":")[1]) for line in offences(PLANTED)]
    # rtol default, rtol=, positional rtol, the scaled atol, approx's rel, the assignment
    assert lines == [6, 7, 8, 12, 14, 15], lines
    assert offences(EXCUSED) == []
