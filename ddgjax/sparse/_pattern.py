"""Fixed sparsity patterns: built once in NumPy, then reused under jit for any values.

A `SparsityPattern` is the set of structurally nonzero positions of a matrix, stored in CSR order
(sorted by row, then column, no duplicates). Operators whose values change with the geometry (the
cotan Laplacian, mass matrices, Hodge stars) keep their pattern and re-assemble only the values, with
gathers and one precomputed permutation: no sorting or deduplication happens inside jit
(DESIGN.md, Architecture).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int


class SparsityPattern(eqx.Module):
    """Positions of the structural nonzeros of an `(n_rows, n_cols)` matrix, in CSR order.

    Attributes:
        rows: `(nnz,)` row index of each stored entry (non-decreasing).
        cols: `(nnz,)` column index of each stored entry (increasing within a row).
        indptr: `(n_rows + 1,)` CSR row pointer: row `i` is `rows[indptr[i]:indptr[i + 1]]`.
        shape: `(n_rows, n_cols)`, static.
    """

    rows: Int[Array, " nnz"]
    cols: Int[Array, " nnz"]
    indptr: Int[Array, " n_rows_plus_1"]
    shape: tuple[int, int] = eqx.field(static=True)

    @property
    def nnz(self) -> int:
        return int(self.rows.shape[0])

    @classmethod
    def from_coo(
        cls, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
    ) -> tuple["SparsityPattern", np.ndarray]:
        """Pattern of a COO list that may repeat positions, and where each entry lands.

        Args:
            rows, cols: `(m,)` integer positions (NumPy; this is topology, built outside jit).
            shape: `(n_rows, n_cols)`.

        Returns:
            `(pattern, slot)`: `slot[k]` is the index in `pattern` that entry `k` is summed into.
        """
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        n_rows, n_cols = int(shape[0]), int(shape[1])
        keys = rows * n_cols + cols
        unique_keys, slot = np.unique(keys, return_inverse=True)
        unique_rows = (unique_keys // n_cols).astype(np.int32)
        unique_cols = (unique_keys % n_cols).astype(np.int32)
        indptr = np.searchsorted(unique_rows, np.arange(n_rows + 1)).astype(np.int32)
        pattern = cls(
            rows=jnp.asarray(unique_rows),
            cols=jnp.asarray(unique_cols),
            indptr=jnp.asarray(indptr),
            shape=(n_rows, n_cols),
        )
        return pattern, slot.reshape(-1).astype(np.int32)
