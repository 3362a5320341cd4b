"""`SparseMatrix`: values on a fixed `SparsityPattern`, differentiable through its values."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, Float

from ._pattern import SparsityPattern


class SparseMatrix(eqx.Module):
    """A sparse matrix whose nonzero *positions* are fixed and whose *values* are JAX arrays.

    The pattern comes from the topology once; new geometry only re-assembles `values`, so every
    function of the values (products, solves, energies) is jit-compiled once and differentiable.

    Attributes:
        values: `(nnz,)` entries in the pattern's CSR order.
        pattern: the `SparsityPattern`.
    """

    values: Float[Array, " nnz"]
    pattern: SparsityPattern

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    def __matmul__(self, x: Float[Array, "n_cols *batch"]) -> Float[Array, "n_rows *batch"]:
        """`A @ x` for a vector `(n_cols,)` or a block of right-hand sides `(n_cols, k)`."""
        products = self.values.reshape((-1,) + (1,) * (x.ndim - 1)) * x[self.pattern.cols]
        return jax.ops.segment_sum(products, self.pattern.rows, num_segments=self.shape[0], indices_are_sorted=True)

    def todense(self) -> Float[Array, "n_rows n_cols"]:
        """Dense copy (for tests and small problems)."""
        return jnp.zeros(self.shape, self.values.dtype).at[self.pattern.rows, self.pattern.cols].add(self.values)

    def to_scipy(self) -> sp.csr_matrix:
        """Host copy as `scipy.sparse.csr_matrix` (same CSR order, no sorting)."""
        return sp.csr_matrix(
            (np.asarray(self.values), np.asarray(self.pattern.cols), np.asarray(self.pattern.indptr)), shape=self.shape
        )
