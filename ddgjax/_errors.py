"""Exceptions raised on structurally bad input (DESIGN.md, Errors and bad input)."""

from __future__ import annotations

import numpy as np


class DDGInputError(ValueError):
    """Malformed input: wrong shape or dtype, out-of-range index, NaN/inf, too few elements."""


class MeshDataError(DDGInputError):
    """A well-formed mesh whose data an operator cannot handle (non-manifold, non-orientable, degenerate faces, ...).

    A `DDGInputError` too: `except DDGInputError` catches every refusal of structurally bad input.
    """


def first_indices(mask: np.ndarray, limit: int = 10) -> str:
    """The first `limit` indices where `mask` is true (rows, for 2-D masks), for error messages."""
    idx = np.flatnonzero(np.asarray(mask).reshape(mask.shape[0], -1).any(axis=1)) if mask.ndim > 1 else np.flatnonzero(mask)
    shown = ", ".join(str(int(i)) for i in idx[:limit])
    more = f", ... ({idx.size} in all)" if idx.size > limit else f" ({idx.size} in all)"
    return f"[{shown}]{more}"


def check_finite(name: str, array: np.ndarray) -> None:
    """Refuse NaN or inf entries, naming the first offending rows."""
    bad = ~np.isfinite(array)
    if bad.any():
        raise DDGInputError(f"{name}: expected finite coordinates, got NaN/inf at rows {first_indices(bad)}")


def check_float_array(name: str, array, trailing: tuple[int, ...], min_rows: int = 1) -> np.ndarray:
    """Host copy of a float array of shape `(n, *trailing)`, refusing bad shape, dtype, NaN/inf."""
    host = np.asarray(array)
    check_float_shape(name, host, trailing, min_rows)
    check_finite(name, host)
    return host


def check_float_shape(name: str, array, trailing: tuple[int, ...], min_rows: int = 1) -> None:
    """Refuse a shape other than `(n, *trailing)` with `n >= min_rows`, or a non-real dtype.

    Shapes and dtypes are known under `jit` too, so traced arrays get the same message as concrete ones.
    """
    shape = np.shape(array)
    dtype = array.dtype if hasattr(array, "dtype") else np.asarray(array).dtype
    expected = "(n, " + ", ".join(map(str, trailing)) + ")"
    if len(shape) != 1 + len(trailing) or shape[1:] != trailing:
        raise DDGInputError(f"{name}: expected shape {expected}, got {shape}")
    if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
        raise DDGInputError(f"{name}: expected a real floating-point array, got dtype {dtype}")
    if shape[0] < min_rows:
        raise DDGInputError(f"{name}: expected at least {min_rows} rows, got {shape[0]}")


def is_traced(array) -> bool:
    """True for JAX tracers (inside jit / grad / vmap), whose values cannot be checked on the host."""
    import jax

    return isinstance(array, jax.core.Tracer)


def check_vertex_indices(name: str, values, n_vertices: int, *, minimum: int = 0) -> np.ndarray:
    """Concrete, distinct, in-range vertex indices (at least `minimum`) as an int64 NumPy array, else `DDGInputError`.

    Every problem with prescribed vertices (Dirichlet data, pins, a boundary cycle) refuses the same
    things with the same words: traced indices (they decide the system's structure), a shape other than
    `(n,)` or a non-integer dtype (an empty list is accepted when `minimum` is 0), indices outside
    `[0, n_vertices)`, repeated vertices.
    """
    if is_traced(values):
        raise DDGInputError(f"{name}: vertex indices decide the system's structure; pass them as host data (NumPy), not traced")
    array = np.asarray(values)
    if array.ndim != 1 or not (array.size == 0 or np.issubdtype(array.dtype, np.integer)):
        raise DDGInputError(
            f"{name}: expected a 1-d integer array of vertex indices, got shape {array.shape} dtype {array.dtype}"
        )
    if array.size < minimum:
        raise DDGInputError(f"{name}: expected at least {'one' if minimum == 1 else minimum} vertex index, got {array.size}")
    array = array.astype(np.int64)
    outside = (array < 0) | (array >= n_vertices)
    if outside.any():
        raise DDGInputError(
            f"{name}: vertex indices must lie in [0, {n_vertices}); out of range at positions {first_indices(outside)}"
        )
    ordered = np.sort(array)  # not `np.unique`, which NumPy 2.4 hashes: ~15x slower on many distinct indices
    if np.any(ordered[1:] == ordered[:-1]):
        raise DDGInputError(f"{name}: expected distinct vertices, got repeated ones")
    return array


def check_count(name: str, value, minimum: int = 1) -> int:
    """A Python / NumPy integer `>= minimum` (not a bool) as an `int`, else `DDGInputError` naming the argument."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise DDGInputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def check_positive(name: str, value) -> float:
    """A finite real number `> 0` (a Python or NumPy number, or a concrete 0-d array) as a `float`, else
    `DDGInputError` naming the argument."""
    try:
        number = np.asarray(value) if not isinstance(value, (str, bytes)) else np.asarray(None)
    except (TypeError, ValueError):  # a ragged sequence
        number = np.asarray(None)
    if not (number.ndim == 0 and number.dtype.kind in "iuf" and np.isfinite(number) and number > 0):
        raise DDGInputError(f"{name}: expected a finite number > 0, got {value!r}")
    return float(number)


def check_choice(name: str, value, choices) -> object:
    """`value` if it is one of `choices`, else `DDGInputError` naming the argument and listing the choices.

    The one validator for option arguments (`kind=`, `method=`, ...) across ddgjax. A NumPy scalar
    counts as its Python value; the type is compared first, so `True` is not taken for `1` and an
    array is refused without being compared.
    """
    plain = value.item() if isinstance(value, np.generic) else value
    if not any(type(plain) is type(choice) and plain == choice for choice in choices):
        raise DDGInputError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return plain
