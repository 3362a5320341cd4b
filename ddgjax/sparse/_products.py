"""The congruence `D^T diag(w) D` onto a fixed pattern, with the slot of every product found once on the host."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, is_traced
from ._gather import gather_sum
from ._matrix import SparseMatrix
from ._pattern import SparsityPattern


class CongruencePlan(eqx.Module):
    """Where each product `w_r D_ra D_rb` of `D^T diag(w) D` lands in a target pattern (from `congruence_plan`).

    Product `r k^2 + a k + b` pairs the `a`-th and `b`-th stored entries of row `r` of `D`.

    Attributes:
        d_cols: `(m, k)` column of each stored entry of `D`, row by row, in the order of its values.
        order: `(p, 1)` the products (`p = m k^2`) sorted by target slot (a stable sort, done on the host).
        inverse_order: `(p, 1)` position of each product in that order.
        sorted_slots: `(p,)` target slot of each sorted product, ascending.
        n_slots: the target pattern's `nnz` (static).
    """

    d_cols: Int[Array, "m k"]
    order: Int[Array, "p 1"]
    inverse_order: Int[Array, "p 1"]
    sorted_slots: Int[Array, " p"]
    n_slots: int = eqx.field(static=True)


def congruence_plan(d_cols: np.ndarray, pattern: SparsityPattern) -> CongruencePlan:
    """Host precomputation for `congruence`: the target slot of every product, sorted (NumPy, once, outside jit).

    Args:
        d_cols: `(m, k)` integer, the `k` columns stored in each row of `D`, in the order of its values
            (e.g. `mesh.topology.edges` for `ddgjax.dec.d0`, whose rows are `[tail, head]`).
        pattern: the `(n, n)` target pattern, with concrete arrays.

    Returns:
        The `CongruencePlan` to pass to `congruence`.

    Raises `DDGInputError` when the pattern lacks a position the product needs.
    """
    d_cols = np.asarray(d_cols)
    if d_cols.ndim != 2 or not np.issubdtype(d_cols.dtype, np.integer):
        raise DDGInputError(f"d_cols: expected an (m, k) integer array, got shape {d_cols.shape} dtype {d_cols.dtype}")
    m, k = d_cols.shape
    i = np.broadcast_to(d_cols[:, :, None], (m, k, k)).reshape(-1)
    j = np.broadcast_to(d_cols[:, None, :], (m, k, k)).reshape(-1)
    slot = pattern.slots(i, j)
    missing = np.flatnonzero(slot >= pattern.nnz)
    if missing.size:
        bad = int(missing[0])
        raise DDGInputError(
            f"pattern: the product D^T W D has an entry at ({int(i[bad])}, {int(j[bad])}) that the target pattern lacks"
        )
    order = np.argsort(slot, kind="stable")
    inverse_order = np.empty_like(order)
    inverse_order[order] = np.arange(order.size)
    return CongruencePlan(
        d_cols=device_array(d_cols, dtype=jnp.int32),
        order=device_array(order[:, None], dtype=jnp.int32),
        inverse_order=device_array(inverse_order[:, None], dtype=jnp.int32),
        sorted_slots=device_array(slot[order], dtype=jnp.int32),
        n_slots=pattern.nnz,
    )


def congruence(
    d: SparseMatrix, /, weights: Float[ArrayLike, " m"], pattern: SparsityPattern, plan: CongruencePlan
) -> SparseMatrix:
    """`D^T diag(w) D` with values on a given `(n, n)` pattern: no sort and no search inside jit.

    `(D^T W D)_ij = sum_r w_r D_ri D_rj`. Every row of `D` holds the same number `k` of stored entries
    (true of the exterior derivatives: `d0` has 2 per edge, `d1` 3 per face). The `m k^2` products are
    permuted into slot order by a fixed gather (`gather_sum`, whose transpose is the inverse
    permutation) and summed by a sorted `segment_sum` (its transpose is a gather), with the order and
    slots from the host-built `plan` (`congruence_plan(d_cols, pattern)`). Linear in `w` and
    differentiable in both modes in `w` and `D`'s values; the result is flagged symmetric.

    Used for operators given by edge weights, `d0^T W d0` (the Hodge decomposition's; with `W = *1`
    it is the cotan Laplacian, a test of `ddgjax.laplacian.cotan_laplacian`). SciPy:
    `D.T @ scipy.sparse.diags(w) @ D`. Reference: Crane et al., *Digital Geometry Processing with
    Discrete Exterior Calculus* (2013), section 3.

    Args:
        d: `(m, n)` matrix, `"csr"` layout or an ELL layout of width `k`, `k` entries in every row, its
            columns those of `plan.d_cols` (checked when concrete; the caller's promise under jit).
        weights: `(m,)` diagonal of `W`.
        pattern: `(n, n)` target pattern, the one the plan was built for.
        plan: `CongruencePlan`.

    Returns:
        `(n, n)` symmetric `SparseMatrix` on `pattern`.
    """
    weights = device_array(weights)
    m, n = d.shape
    per_row = plan.d_cols.shape[1]
    if (
        plan.d_cols.shape[0] != m
        or d.pattern.nnz != m * per_row
        or weights.shape != (m,)
        or pattern.shape != (n, n)
        or pattern.nnz != plan.n_slots
    ):
        raise DDGInputError(
            f"congruence: expected D (m, n) with {per_row} stored entries in each of m = {plan.d_cols.shape[0]} rows, "
            f"weights (m,) and an (n, n) pattern with {plan.n_slots} slots (the plan's); got D {d.shape} with "
            f"{d.pattern.nnz} stored entries, weights {weights.shape}, pattern {pattern.shape} with {pattern.nnz} slots"
        )
    if d.pattern.layout == "csr":
        cols, values = d.pattern.cols.reshape(m, per_row), d.values.reshape(m, per_row)
    elif d.pattern.layout == "ell" and d.pattern.width == per_row:
        cols, values = d.pattern.cols.reshape(per_row, m).T, d.values.reshape(per_row, m).T
    else:
        raise DDGInputError(f"d: expected a 'csr' pattern or an ELL pattern of width {per_row}, got {d.pattern.layout!r}")
    if not (is_traced(cols) or is_traced(plan.d_cols)) and not np.array_equal(np.asarray(cols), np.asarray(plan.d_cols)):
        raise DDGInputError("plan: built for a D with other columns (congruence_plan(d_cols, pattern) must use D's own columns)")
    products = weights[:, None, None] * values[:, :, None] * values[:, None, :]
    in_slot_order = gather_sum(products.reshape(-1), plan.order, plan.inverse_order)
    summed = jax.ops.segment_sum(in_slot_order, plan.sorted_slots, num_segments=pattern.nnz, indices_are_sorted=True)
    return SparseMatrix(summed, pattern, symmetric=True)
