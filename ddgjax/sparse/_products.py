"""Fixed-pattern products assembled inside jit: the congruence `D^T diag(w) D` onto a given pattern."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import DDGInputError, is_traced
from ._matrix import SparseMatrix
from ._pattern import SparsityPattern


def congruence(d: SparseMatrix, weights: Float[Array, " m"], pattern: SparsityPattern) -> SparseMatrix:
    """`D^T diag(w) D` with values on a given `(n, n)` pattern (no sort, no host work: jit-safe).

    `(D^T W D)_ij = sum_r w_r D_ri D_rj`. Each row of `D` must hold the same number `k` of stored
    entries (true of the exterior derivatives: `d0` has 2 per edge, `d1` 3 per face); its `k^2`
    products per row are located in `pattern` (a scan over ELL slots, a bisection in the sorted
    tail / CSR storage) and summed there. Used for the DEC Laplacian `d0^T *1 d0` on
    `mesh.vertex_pattern`. A product that falls outside `pattern` raises `DDGInputError` when the
    pattern is concrete (under jit it cannot be checked and is dropped).

    Args:
        d: `(m, n)` matrix with `k` entries in every row.
        weights: `(m,)` diagonal of `W`.
        pattern: `(n, n)` target pattern containing the product's structure.
    """
    m, n = d.shape
    per_row, remainder = divmod(d.pattern.nnz, m)
    if remainder or pattern.shape != (n, n) or weights.shape != (m,):
        raise DDGInputError(
            f"congruence: expected D (m, n) with the same number of entries in every row, weights (m,) and a "
            f"({n}, {n}) pattern; got D {d.shape} with {d.pattern.nnz} stored entries, weights {weights.shape}, "
            f"pattern {pattern.shape}"
        )
    if d.pattern.layout == "csr":
        cols = d.pattern.cols.reshape(m, per_row)
        values = d.values.reshape(m, per_row)
    else:
        cols = d.pattern.cols.reshape(per_row, m).T
        values = d.values.reshape(per_row, m).T
    products = weights[:, None, None] * values[:, :, None] * values[:, None, :]
    i = jnp.broadcast_to(cols[:, :, None], products.shape).reshape(-1)
    j = jnp.broadcast_to(cols[:, None, :], products.shape).reshape(-1)
    slot = find_slots(pattern, i, j)
    if not is_traced(slot) and bool(np.any(np.asarray(slot) >= pattern.nnz)):
        bad = int(np.flatnonzero(np.asarray(slot) >= pattern.nnz)[0])
        raise DDGInputError(
            f"pattern: the product D^T W D has an entry at ({int(i[bad])}, {int(j[bad])}) that the target pattern lacks"
        )
    return SparseMatrix(jax.ops.segment_sum(products.reshape(-1), slot, num_segments=pattern.nnz), pattern)


def find_slots(pattern: SparsityPattern, i: Int[Array, " p"], j: Int[Array, " p"]) -> Int[Array, " p"]:
    """Storage slot of each position `(i, j)` in `pattern`, or `pattern.nnz` where it has none (jit-safe)."""
    n_rows = pattern.shape[0]
    missing = jnp.full(i.shape, pattern.nnz, dtype=jnp.int32)
    if pattern.layout == "csr":
        return _bisect(pattern.rows, pattern.cols, i, j, 0, missing)
    ell_size = n_rows * pattern.width
    slot = missing
    for k in range(pattern.width):
        candidate = k * n_rows + i
        # A padding slot repeats an existing position with value 0: keep the first (real) match.
        hit = (pattern.cols[candidate] == j) & (slot == pattern.nnz)
        slot = jnp.where(hit, candidate, slot)
    if pattern.nnz > ell_size:
        slot = jnp.where(slot == pattern.nnz, _bisect(pattern.rows[ell_size:], pattern.cols[ell_size:], i, j, ell_size, missing), slot)
    return slot


def _bisect(rows, cols, i, j, offset: int, missing):
    """Position of `(i, j)` in lexicographically sorted `(rows, cols)` plus `offset`, else `missing`."""
    size = rows.shape[0]
    lo = jnp.zeros(i.shape, dtype=jnp.int32)
    hi = jnp.full(i.shape, size, dtype=jnp.int32)
    for _ in range(int(size).bit_length()):
        mid = (lo + hi) // 2
        safe = jnp.minimum(mid, size - 1)
        less = (rows[safe] < i) | ((rows[safe] == i) & (cols[safe] < j))
        active = lo < hi
        lo, hi = jnp.where(active & less, mid + 1, lo), jnp.where(active & ~less, mid, hi)
    found = jnp.minimum(lo, size - 1)
    match = (lo < size) & (rows[found] == i) & (cols[found] == j)
    return jnp.where(match, found + offset, missing)
