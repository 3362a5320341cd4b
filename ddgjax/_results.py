"""Outcomes of computations whose success depends on values inside `jit` (DESIGN.md, errors).

As lineax and optimistix do it: a computation that can fail on its values (a flow step that makes a
curve self-intersect, a solve that does not converge, a matrix that is not positive definite)
returns an object with a `result` field, an item of `RESULTS`, and takes `throw=True`: by default a
failure raises through `equinox.error_if` (inside `jit` too, at run time, with the item's message);
with `throw=False` nothing raises and the caller inspects `result` (`result == RESULTS.successful`).
Never a sentinel value, never a NaN that hides the failure. Under `vmap`, `throw=True` raises when
any batch member failed.

Reference: optimistix `RESULTS` / lineax `RESULTS` (`equinox.Enumeration`, `throw=`).
"""

from __future__ import annotations

import equinox as eqx
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
        "The iterative solver did not reach its tolerance within `max_steps` iterations. Raise "
        '`max_steps`, loosen `rtol`, or use a direct method (`method="cholesky"`); pass `throw=False` '
        "to inspect the result."
    )
    singular = (
        "The solution does not solve the system to `residual_tolerance`: the matrix is singular (a "
        "closed surface's Laplacian has constant null vectors: fix a value or use a problem-level "
        "solver that projects them out) or too ill-conditioned. Pass `throw=False` to inspect it."
    )
    nonfinite = (
        "The computation produced NaN or inf values (for a flow: non-finite input points, which "
        "are checked only outside jit, or positions that overflowed). Pass `throw=False` to keep "
        "the values and inspect `result`."
    )


def raise_if_failed(value: PyTree, result: RESULTS, throw: bool) -> PyTree:
    """`value`, unchanged; when `throw` is true, an `equinox.error_if` that raises `result`'s message unless successful."""
    if not throw:
        return value
    # A concrete success needs no check threaded onto `value` (equinox's check costs a dispatch).
    if not result.is_traced() and not bool(is_failure(result)):
        return value
    return result.error_if(value, is_failure(result))


def is_failure(result: RESULTS) -> Bool[Array, "..."]:
    """`result != RESULTS.successful` (elementwise under `vmap`)."""
    return result != RESULTS.successful
