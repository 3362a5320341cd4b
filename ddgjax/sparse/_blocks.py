"""Free-free and free-fixed blocks of a square matrix for Dirichlet conditions, on patterns built once.

A Dirichlet problem `A u = b` with `u` given on a set of fixed indices `c` (boundary vertices, pinned
vertices) and unknown on the free rest `f` reduces to `A_ff u_f = b_f - A_fc u_c` (libigl's
`min_quad_with_fixed`, gpytoolbox's `min_quad_with_fixed`). Which positions of `A` land in which
block depends only on the pattern and the index sets, so `dirichlet_plan` finds them once on the host
(NumPy) and builds both block patterns; `dirichlet_blocks` then fills them from any values on that
pattern with one fixed gather per block (`gather_sum`, whose reverse pass is a gather as well), inside
jit, grad and vmap: the blocks of the cotan Laplacian of moving vertices cost no host work per step.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, first_indices, is_traced
from ._gather import gather_sum
from ._matrix import SparseMatrix, _flags
from ._pattern import SparsityPattern


class DirichletPlan(eqx.Module):
    """Where the free-free and free-fixed blocks of an `(n, n)` matrix read its values (from `dirichlet_plan`).

    Attributes:
        free: `(n_free,)` the free indices, ascending: row / column `k` of `A_ff` is `free[k]` of `A`.
        fixed: `(n_fixed,)` the fixed indices in the caller's order: column `k` of `A_fc` is `fixed[k]`.
        free_free: the `(n_free, n_free)` pattern of `A_ff` (host-built ELL; symmetric when `A`'s is).
        free_fixed: the `(n_free, n_fixed)` pattern of `A_fc`.
        free_free_source: `(free_free.nnz, 1)` the slot of `A` each slot of `A_ff` reads
            (`n_slots` for padding: reads 0).
        free_free_readers: `(n_slots, 1)` its transpose, the slot of `A_ff` reading each slot of `A`
            (`free_free.nnz` where none does), for a scatter-free reverse pass (`gather_sum`).
        free_fixed_source, free_fixed_readers: the same for `A_fc`.
        position: `(n,)` the position of each index in `[free | fixed]` (for `join`).
        n_slots: storage length (`pattern.nnz`) of the matrices the plan applies to, static.
    """

    free: Int[Array, " n_free"]
    fixed: Int[Array, " n_fixed"]
    free_free: SparsityPattern
    free_fixed: SparsityPattern
    free_free_source: Int[Array, "nnz_ff 1"]
    free_free_readers: Int[Array, "n_slots 1"]
    free_fixed_source: Int[Array, "nnz_fc 1"]
    free_fixed_readers: Int[Array, "n_slots 1"]
    position: Int[Array, " n"]
    n_slots: int = eqx.field(static=True)

    def join(
        self, free_values: Float[ArrayLike, " n_free *k"], fixed_values: Float[ArrayLike, " n_fixed *k"]
    ) -> Float[Array, " n *k"]:
        """The full `(n, ...)` vector (or block) with `free_values` at `free` and `fixed_values` at `fixed`.

        One permutation gather of `[free_values | fixed_values]` (its reverse pass a gather too), so
        `u = plan.join(u_f, u_c)` after solving `A_ff u_f = b_f - A_fc u_c`. libigl: the full `Z`
        that `min_quad_with_fixed` returns.
        """
        free_values, fixed_values = device_array(free_values), device_array(fixed_values)
        n_free, n_fixed = self.free.shape[0], self.fixed.shape[0]
        if free_values.shape[:1] != (n_free,) or fixed_values.shape != (n_fixed,) + free_values.shape[1:]:
            raise DDGInputError(
                f"free_values, fixed_values: expected shapes ({n_free}, ...) and ({n_fixed}, ...) with equal trailing "
                f"axes, got {free_values.shape} and {fixed_values.shape}"
            )
        stacked = jnp.concatenate([free_values, fixed_values.astype(free_values.dtype)])
        # The transpose of "read position[i]" is "read the index at each position": [free | fixed].
        return gather_sum(stacked, self.position[:, None], jnp.concatenate([self.free, self.fixed])[:, None])


def dirichlet_plan(matrix: SparseMatrix | SparsityPattern, fixed: Int[ArrayLike, " n_fixed"]) -> DirichletPlan:
    """Host precomputation for `dirichlet_blocks`: the free indices and both block patterns (NumPy, once).

    The free indices are the complement of `fixed`, ascending (libigl's `unknown`); the columns of
    `A_fc` follow `fixed` in the caller's order (libigl's `known`). Positions are the distinct stored
    positions of the pattern (`SparsityPattern.entries`), explicitly stored zeros included, as
    `A.to_scipy()` has them. Build it once per pattern and index set (outside jit: it needs
    concrete arrays), then call `dirichlet_blocks(A, plan)` for any values on that pattern.

    Args:
        matrix: the square `SparseMatrix`, or its `SparsityPattern` (only the pattern is used).
        fixed: `(n_fixed,)` distinct integer indices in `[0, n)` (may be empty); at least one index
            must stay free.

    Returns:
        `DirichletPlan`.

    Raises `DDGInputError` for a non-square matrix, and for `fixed` not 1-d integer, traced, out of
    range, repeated, or covering every index.
    """
    if isinstance(matrix, SparseMatrix):
        matrix = matrix.pattern
    if not isinstance(matrix, SparsityPattern):
        raise DDGInputError(
            f"matrix: expected a SparseMatrix or its SparsityPattern, got {type(matrix).__name__} "
            "(ddgjax.sparse.from_scipy converts a SciPy matrix)"
        )
    pattern = matrix
    n = pattern.shape[0]
    if pattern.shape[1] != n:
        raise DDGInputError(f"matrix: Dirichlet blocks need a square matrix, got shape {pattern.shape}")
    fixed = _check_fixed(fixed, n)
    is_fixed = np.zeros(n, dtype=bool)
    is_fixed[fixed] = True
    free = np.flatnonzero(~is_fixed)
    position = np.empty(n, dtype=np.int64)
    position[free] = np.arange(free.size)
    position[fixed] = free.size + np.arange(fixed.size)
    rows, cols, slot = pattern.entries()
    free_row = ~is_fixed[rows]
    blocks = []
    for in_block, shape, offset in (
        (free_row & ~is_fixed[cols], (free.size, free.size), 0),
        (free_row & is_fixed[cols], (free.size, fixed.size), free.size),
    ):
        block_pattern, block_slot = _block_pattern(position[rows[in_block]], position[cols[in_block]] - offset, shape)
        source = np.full(block_pattern.nnz, pattern.nnz, dtype=np.int32)
        source[block_slot] = slot[in_block]
        readers = np.full(pattern.nnz, block_pattern.nnz, dtype=np.int32)
        readers[slot[in_block]] = block_slot  # each slot of A lands in at most one block slot
        blocks.append((block_pattern, device_array(source[:, None]), device_array(readers[:, None])))
    (free_free, ff_source, ff_readers), (free_fixed, fc_source, fc_readers) = blocks
    return DirichletPlan(
        free=device_array(free, dtype=jnp.int32),
        fixed=device_array(fixed, dtype=jnp.int32),
        free_free=free_free,
        free_fixed=free_fixed,
        free_free_source=ff_source,
        free_free_readers=ff_readers,
        free_fixed_source=fc_source,
        free_fixed_readers=fc_readers,
        position=device_array(position, dtype=jnp.int32),
        n_slots=pattern.nnz,
    )


class DirichletBlocks(NamedTuple):
    """The two blocks `dirichlet_blocks` returns (unpacks as `A_ff, A_fc = dirichlet_blocks(A, plan)`).

    Attributes:
        free_free: `(n_free, n_free)` `A_ff = A[free][:, free]`, the matrix of the reduced system, on
            `plan.free_free`, with `A`'s symmetry and semidefinite flags.
        free_fixed: `(n_free, n_fixed)` `A_fc = A[free][:, fixed]`, which moves the fixed values to the
            right-hand side (`b_f - A_fc u_c`), on `plan.free_fixed`, unflagged.
    """

    free_free: SparseMatrix
    free_fixed: SparseMatrix


def dirichlet_blocks(matrix: SparseMatrix, plan: DirichletPlan | Int[ArrayLike, " n_fixed"]) -> DirichletBlocks:
    """The free-free block `A_ff = A[f][:, f]` and the free-fixed block `A_fc = A[f][:, c]` of a square matrix.

    With `c` the fixed indices and `f` the free rest (ascending), a Dirichlet problem `A u = b`,
    `u_c` given, becomes `A_ff u_f = b_f - A_fc u_c` (and `u = plan.join(u_f, u_c)`). Each block's
    values are one fixed gather of `A.values` (`gather_sum`): no search inside jit, linear and
    differentiable in `A.values` in both modes, and batched by `vmap` over values. `A_ff` keeps `A`'s
    `symmetric` / `positive_semidefinite` / `negative_semidefinite` flags (a principal submatrix of
    a semidefinite matrix is semidefinite); `A_fc` has none.

    SciPy: `A[free][:, free]`, `A[free][:, fixed]`. libigl / gpytoolbox: the `Aeq`-free case of
    `min_quad_with_fixed` (`igl.min_quad_with_fixed(A, B, known, Y, ...)` factors `A(unknown, unknown)`
    and moves `A(unknown, known) Y` to the right-hand side).

    Args:
        matrix: `(n, n)` `SparseMatrix` on the pattern the plan was built for (checked when the
            pattern is concrete; the caller's promise under jit).
        plan: a `DirichletPlan` from `dirichlet_plan(A, fixed)` (build once, reuse inside jit), or the
            fixed indices themselves (the plan is then built on the host at every call, which needs
            concrete pattern arrays).

    Returns:
        `DirichletBlocks(free_free, free_fixed)`: `A_ff` and `A_fc`, `(n_free, n_free)` and
        `(n_free, n_fixed)` `SparseMatrix`es on `plan.free_free` and `plan.free_fixed`.
    """
    if not isinstance(matrix, SparseMatrix):
        raise DDGInputError(
            f"matrix: expected a SparseMatrix, got {type(matrix).__name__} (ddgjax.sparse.from_scipy converts a SciPy matrix)"
        )
    if not isinstance(plan, DirichletPlan):
        plan = dirichlet_plan(matrix.pattern, plan)
    n = plan.position.shape[0]
    if matrix.shape != (n, n) or matrix.pattern.nnz != plan.n_slots:
        raise DDGInputError(
            f"plan: built for an ({n}, {n}) pattern with {plan.n_slots} slots, got a matrix of shape {matrix.shape} "
            f"with {matrix.pattern.nnz} (build it with dirichlet_plan(A, fixed) for this matrix's pattern)"
        )
    _check_positions(matrix.pattern, plan)
    free_free = gather_sum(matrix.values, plan.free_free_source, plan.free_free_readers)
    free_fixed = gather_sum(matrix.values, plan.free_fixed_source, plan.free_fixed_readers)
    return DirichletBlocks(SparseMatrix(free_free, plan.free_free, **_flags(matrix)), SparseMatrix(free_fixed, plan.free_fixed))


def _check_fixed(fixed, n: int) -> np.ndarray:
    """`fixed` as int64 host indices, or `DDGInputError` naming what is wrong with it."""
    if is_traced(fixed):
        raise DDGInputError(
            "fixed: the fixed indices decide the block shapes, so they must be concrete (a NumPy array), not "
            "traced; build the plan with dirichlet_plan(A, fixed) outside jit and pass it in"
        )
    fixed = np.asarray(fixed)
    if fixed.ndim != 1 or not (fixed.size == 0 or np.issubdtype(fixed.dtype, np.integer)):
        raise DDGInputError(f"fixed: expected a 1-d integer array of indices, got shape {fixed.shape} dtype {fixed.dtype}")
    fixed = fixed.astype(np.int64)
    outside = (fixed < 0) | (fixed >= n)
    if outside.any():
        raise DDGInputError(f"fixed: indices must lie in [0, {n}); out of range at positions {first_indices(outside)}")
    repeated = np.zeros(fixed.size, dtype=bool)
    repeated[np.sort(np.unique(fixed, return_index=True)[1])] = True
    if not repeated.all():
        raise DDGInputError(f"fixed: indices must be distinct; repeated at positions {first_indices(~repeated)}")
    if fixed.size == n:
        raise DDGInputError(f"fixed: all {n} indices are fixed, so no free index is left")
    return fixed


def _block_pattern(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> tuple[SparsityPattern, np.ndarray]:
    """Pattern of distinct positions, and the storage slot of each (`SparsityPattern.from_coo`)."""
    if shape[1] == 0:
        # No fixed index: an empty CSR pattern (an ELL one would pad at column 0, which does not exist).
        empty = jnp.zeros(0, dtype=jnp.int32)
        indptr = jnp.zeros(shape[0] + 1, dtype=jnp.int32)
        return SparsityPattern(rows=empty, cols=empty, indptr=indptr, shape=shape), np.zeros(0, dtype=np.int32)
    return SparsityPattern.from_coo(rows, cols, shape)


def _check_positions(pattern: SparsityPattern, plan: DirichletPlan) -> None:
    """Refuse a plan built for another pattern with the same shape and storage length (host, when concrete)."""
    arrays = (pattern.rows, pattern.cols, plan.free, plan.free_free_source, plan.free_fixed_source)
    if any(is_traced(array) for array in arrays):
        return
    rows, cols = np.asarray(pattern.rows), np.asarray(pattern.cols)
    free, fixed = np.asarray(plan.free), np.asarray(plan.fixed)
    for block, source, col_indices in (
        (plan.free_free, plan.free_free_source, free),
        (plan.free_fixed, plan.free_fixed_source, fixed),
    ):
        source = np.asarray(source)[:, 0]
        real = source < plan.n_slots
        expected_rows = free[np.asarray(block.rows)[real]]
        expected_cols = col_indices[np.asarray(block.cols)[real]]
        if not (np.array_equal(rows[source[real]], expected_rows) and np.array_equal(cols[source[real]], expected_cols)):
            raise DDGInputError("plan: built for a matrix with other stored positions (use dirichlet_plan(A, fixed) for A)")
