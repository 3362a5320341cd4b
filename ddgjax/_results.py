"""Outcomes of computations whose success depends on values inside `jit` (DESIGN.md, errors).

As lineax and optimistix do it: a computation that can fail on its values (a flow step that makes a
curve self-intersect, a solve that does not converge, a matrix that is not positive definite)
takes `throw=True`: by default a failure raises through `equinox.error_if` (inside `jit` too, at run
time, with the item's message); with `throw=False` nothing raises and the caller inspects the outcome.
Never a sentinel value, never a NaN that hides the failure. Under `vmap`, `throw=True` raises when
any batch member failed. What the caller gets back (docs/conventions.md, "Outcomes"):

- a function whose answer is a value (an array, or a named tuple of arrays such as `Eigenpairs`)
  returns the value with `throw=True`, and with `throw=False` a `Solution` holding `value`,
  `result` and `stats` (lineax's and optimistix's shape); `outcome(value, result, throw)` is the one
  place that makes this choice;
- a driver whose answer is a record of its run (`linear_solve`'s `LinearSolution`, the flows,
  `minimize_shape`, `match_shapes`) always returns the record, which carries `value`, `result` and
  `stats` itself.

Every such record, `Solution` included, is a `Record`: one shape (`value`, `result`, `stats`) that a
caller can rely on whatever returned it.

Every outcome is an item of `RESULTS`; no computation raises through a bare `equinox.error_if` with a
message of its own.

Reference: optimistix `RESULTS` / lineax `RESULTS` (`equinox.Enumeration`, `throw=`).
"""

from typing import Any

import equinox as eqx
import jax
import numpy as np
from equinox import AbstractVar  # (no `from __future__ import annotations` here: equinox reads AbstractVar as an object)
from jaxtyping import Array, Bool, PyTree


class RESULTS(eqx.Enumeration):
    """Every outcome a ddgjax computation reports; the message is what `throw=True` raises with."""

    successful = ""
    self_intersection = (
        "The curve was not simple at some step of the flow (it crossed or touched itself, or "
        "already did at the start; `first_failure_step` says when). The discrete flows do not "
        "keep a curve simple: a `tau` above the explicit stability limit causes it, and so does "
        "a short edge collapsing at any `tau`. Pass `throw=False` to keep the states and "
        "inspect `result`."
    )
    max_steps_reached = (
        "The iteration did not reach its tolerance within `max_steps` iterations (an iterative linear "
        "solve's, or the function's own loop: ARAP's local-global steps, ICP's refinements, the "
        "Newton solve of an implicit time step). Raise `max_steps` or loosen `rtol`; for a linear solve, "
        'a direct backend (`solver="cholesky"`) avoids the iteration; for a time step that does not '
        "converge (`euler_flow`), a smaller `tau`. Pass `throw=False` to inspect the result."
    )
    singular = (
        "The solution does not solve the system to `residual_tolerance`: the matrix is singular (a "
        "closed surface's Laplacian has constant null vectors: fix a value or use a problem-level "
        "solver that projects them out) or too ill-conditioned. In float32 (JAX's default precision) "
        "round-off alone can leave a well-posed mesh system above the tolerance: enable float64 with "
        '`jax.config.update("jax_enable_x64", True)` before making arrays. Pass `throw=False` to inspect it.'
    )
    nonfinite = (
        "The computation met or produced NaN or inf values: an input that could only be checked when "
        "the program ran (values traced inside `jit`: a right-hand side, matrix values, positions), or "
        "values that overflowed on the way. Pass `throw=False` to keep the values and inspect `result`."
    )
    eigensolver_failed = (
        "The eigensolver did not converge to the requested eigenpairs (the subspace iteration ran out "
        "of steps, or its basis lost rank), or its pairs do not solve the problem to round-off (a "
        "Laplacian with faces of near-zero area is too ill-conditioned for them: `ddgjax.mesh.check_mesh` "
        "lists those faces and `robust=True` handles them on a triangle mesh; on a tet mesh "
        "`ddgjax.volume.check_tet_mesh` lists flat tets, to repair): raise `k` by a few (a cluster cut at `k`), or use "
        '`method="arpack"`. Pass `throw=False` to inspect the result.'
    )
    not_positive_definite = (
        "A matrix that must be positive definite is not (a factorisation met a non-positive pivot, "
        "a mass matrix has a non-positive row sum, or a Laplacian flagged positive semidefinite has a "
        "negative eigenvalue): the mesh has degenerate or inverted elements (`ddgjax.mesh.check_mesh` "
        "lists zero-area faces, which `robust=True` handles; `ddgjax.volume.check_tet_mesh` lists flat "
        "and inverted tets, which only a repair fixes), or the "
        "shift / time step makes the system indefinite, or the matrix is singular (a closed surface's "
        "Laplacian; a graph whose zero edge weights, traced inside `jit`, cut a piece off every fixed "
        "vertex). In float32 (JAX's default precision) round-off can tip a nearly singular matrix "
        'over: enable float64 with `jax.config.update("jax_enable_x64", True)`. Pass `throw=False` to '
        "inspect the result."
    )
    negative_value = (
        "A value declared non-negative with `ddgjax.sparse.nonnegative(t)` (a time step, a shift, a "
        "weight) was negative or NaN when the program ran, so the matrix scaled by it would be flagged "
        "semidefinite without being so. Pass a value >= 0 (and not NaN)."
    )
    coincident_vertices = (
        "The mesh has an edge of zero length (two vertices at one point), where the tangent directions and "
        "corner angles that carry vectors from vertex to vertex are undefined: `robust=True` keeps the scalar "
        "operators finite there, but transported vectors and log-map directions near and beyond those "
        "vertices have no meaning. Merge the coincident vertices (`ddgjax.mesh.check_mesh` lists the "
        "zero-length edges; trimesh's `Trimesh.merge_vertices()`). Pass `throw=False` to keep the values."
    )
    missing_diagonal = (
        "A diagonal was added onto a sparse matrix whose pattern lacks diagonal entries (`A + D` or "
        "`A.shifted(s)` on a CSR pattern passed into `jit`, which cannot be checked before the program "
        "runs): there is no slot to add them to. Assemble the matrix on a pattern that stores its whole "
        "diagonal (explicit zeros count), e.g. `ddgjax.sparse.from_scipy(A + 0 * scipy.sparse.identity(n))`."
    )


class Record(eqx.Module):
    """What every record of a computation that can fail has (lineax's and optimistix's `Solution` names).

    Attributes:
        value: the answer (for a run: its final state, as lineax's solution and optimistix's `y`).
        result: an item of `RESULTS`; `RESULTS.successful` when `value` is the answer. For a run of
            steps, the first failing step's outcome (and `first_failure_step` says which).
        stats: what the computation measured on the way (residuals, iteration counts, a run's history),
            a dict of arrays.

    A subclass provides each as a field or a property (`equinox.AbstractVar`).
    """

    value: AbstractVar[PyTree]
    result: AbstractVar[RESULTS]
    stats: AbstractVar[dict[str, Any]]


class Solution(Record):
    """A value with its outcome: what a computation that can fail returns with `throw=False`.

    Attributes:
        value: the answer (an array or a pytree of arrays, as the function returns with `throw=True`).
        result: an item of `RESULTS`; `RESULTS.successful` when `value` is the answer.
        stats: what the computation measured on the way (solver residuals, iteration counts,
            energies); a dict of arrays, possibly empty.

    Reference: lineax `Solution`, optimistix `Solution`.
    """

    value: PyTree
    result: RESULTS
    stats: dict[str, Any]


def outcome(value: PyTree, result: RESULTS, throw: bool, stats: dict[str, Any] | None = None) -> PyTree:
    """`value` (raising `result`'s message on failure) when `throw`, else `Solution(value, result, stats)`."""
    if throw:
        return raise_if_failed(value, result, throw=True)
    return Solution(value=value, result=result, stats={} if stats is None else stats)


def first_failure(*results: RESULTS) -> RESULTS:
    """The first of `results` that is not a success (elementwise under `vmap`), else `RESULTS.successful`."""
    combined = results[-1]
    for result in reversed(results[:-1]):
        combined = RESULTS.where(is_failure(result), result, combined)
    return combined


def raise_if_failed(value: PyTree, result: RESULTS, throw: bool) -> PyTree:
    """`value`, unchanged; when `throw` is true, an `equinox.error_if` that raises `result`'s message unless successful."""
    if not throw:
        return value
    # A concrete success needs no check threaded onto `value` (equinox's check costs a dispatch). The
    # item's index (equinox's `_value`) is read on the host rather than compared by a dispatched JAX op.
    index = result._value
    if not isinstance(index, jax.core.Tracer) and np.all(np.asarray(index) == RESULTS.successful._value):
        return value
    return result.error_if(value, is_failure(result))


def is_failure(result: RESULTS) -> Bool[Array, "..."]:
    """`result != RESULTS.successful` (elementwise under `vmap`)."""
    return result != RESULTS.successful
