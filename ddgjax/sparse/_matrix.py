"""`SparseMatrix`: values on a fixed `SparsityPattern`, differentiable through its values."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import scipy.sparse as sp
from jax.experimental import sparse as jsparse
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError, is_traced
from ._pattern import SparsityPattern


class SparseMatrix(eqx.Module):
    """A sparse matrix whose nonzero *positions* are fixed and whose *values* are JAX arrays.

    The pattern comes from the topology once; new geometry only re-assembles `values`, so every
    function of the values (products, solves, energies) is jit-compiled once and differentiable
    (`jax.grad` / `jax.jvp` / `jax.vmap` through `values` and through the right-hand side).

    Arithmetic: `A @ x` (`x` of shape `(n_cols,)` or `(n_cols, k)`), `A.T`, `A + B`, `A - B` (same
    pattern), `-A`, `c * A`, `A / c`, `A.diagonal()`; exports `todense()`, `to_scipy()`, `to_bcoo()`,
    `as_lineax_operator(...)`.

    Attributes:
        values: `(nnz,)` entries in the pattern's storage order (see `SparsityPattern`; padding slots
            of an ELL pattern hold 0).
        pattern: the `SparsityPattern`.
    """

    values: Float[Array, " nnz"] = eqx.field(converter=jnp.asarray)
    pattern: SparsityPattern

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    @property
    def dtype(self):
        return self.values.dtype

    def __matmul__(self, x: Float[ArrayLike, "n_cols *batch"]) -> Float[Array, "n_rows *batch"]:
        """`A @ x` for a vector `(n_cols,)` or a block of right-hand sides `(n_cols, k)`."""
        if not is_traced(x) and (np.ndim(x) == 0 or np.shape(x)[0] != self.shape[1]):
            raise DDGInputError(f"x: expected shape ({self.shape[1]},) or ({self.shape[1]}, k), got {np.shape(x)}")
        x = jnp.asarray(x)
        pattern = self.pattern
        if pattern.layout == "csr":
            products = _broadcast(self.values, x) * x[pattern.cols]
            return jax.ops.segment_sum(products, pattern.rows, num_segments=self.shape[0], indices_are_sorted=True)
        n_rows, width = self.shape[0], pattern.width
        ell_values = self.values[: n_rows * width].reshape(width, n_rows)
        ell_cols = pattern.cols[: n_rows * width].reshape(width, n_rows)
        # `width` contiguous multiply-adds; XLA fuses them into one pass over the rows.
        if pattern.diagonal_first:
            result = _broadcast(ell_values[0], x) * x
        else:
            result = _broadcast(ell_values[0], x) * x[ell_cols[0]]
        for k in range(1, width):
            result = result + _broadcast(ell_values[k], x) * x[ell_cols[k]]
        if pattern.nnz > n_rows * width:
            tail = slice(n_rows * width, None)
            result = result + jax.ops.segment_sum(
                _broadcast(self.values[tail], x) * x[pattern.cols[tail]],
                pattern.rows[tail],
                num_segments=n_rows,
                indices_are_sorted=True,
            )
        return result

    @property
    def T(self) -> "SparseMatrix":
        """Transpose: a permutation of the values (host-built patterns), else a COO re-labelling."""
        pattern = self.pattern
        if pattern.symmetric:
            if pattern.transpose_slot is None:
                return self
            return SparseMatrix(self.values[pattern.transpose_slot], pattern)
        if pattern.transpose_pattern is not None:
            values = jnp.take(self.values, pattern.transpose_slot, mode="fill", fill_value=0)
            return SparseMatrix(values, pattern.transpose_pattern)
        return _coo_transpose(self)

    def __add__(self, other: "SparseMatrix") -> "SparseMatrix":
        _check_same_pattern(self, other, "+")
        return SparseMatrix(self.values + other.values, self.pattern)

    def __sub__(self, other: "SparseMatrix") -> "SparseMatrix":
        _check_same_pattern(self, other, "-")
        return SparseMatrix(self.values - other.values, self.pattern)

    def __neg__(self) -> "SparseMatrix":
        return SparseMatrix(-self.values, self.pattern)

    def __mul__(self, scalar) -> "SparseMatrix":
        if isinstance(scalar, SparseMatrix) or np.ndim(scalar) != 0:
            raise DDGInputError(
                f"scalar: SparseMatrix * c needs a scalar c (use A @ x for products), got shape {np.shape(scalar)}"
            )
        return SparseMatrix(self.values * scalar, self.pattern)

    __rmul__ = __mul__

    def __truediv__(self, scalar) -> "SparseMatrix":
        return self * (1.0 / scalar)

    def diagonal(self) -> Float[Array, " n"]:
        """The main diagonal, `(min(n_rows, n_cols),)` (zeros where the pattern has no diagonal entry)."""
        pattern = self.pattern
        n = min(self.shape)
        if pattern.diagonal_first:
            return self.values[:n]
        on_diagonal = pattern.rows == pattern.cols
        return jax.ops.segment_sum(jnp.where(on_diagonal, self.values, 0), jnp.where(on_diagonal, pattern.rows, n), n)

    def row_sums(self) -> Float[Array, " n_rows"]:
        """`A @ 1` without the gather: the sum of each row's stored values, `(n_rows,)`."""
        pattern = self.pattern
        n_rows = self.shape[0]
        if pattern.layout == "csr":
            return jax.ops.segment_sum(self.values, pattern.rows, num_segments=n_rows, indices_are_sorted=True)
        ell_size = n_rows * pattern.width
        ell_values = self.values[:ell_size].reshape(pattern.width, n_rows)
        sums = ell_values[0]
        for k in range(1, pattern.width):
            sums = sums + ell_values[k]
        if pattern.nnz > ell_size:
            sums = sums + jax.ops.segment_sum(
                self.values[ell_size:], pattern.rows[ell_size:], num_segments=n_rows, indices_are_sorted=True
            )
        return sums

    def todense(self) -> Float[Array, "n_rows n_cols"]:
        """Dense copy (for tests and small problems)."""
        return jnp.zeros(self.shape, self.values.dtype).at[self.pattern.rows, self.pattern.cols].add(self.values)

    def to_bcoo(self) -> jsparse.BCOO:
        """`jax.experimental.sparse.BCOO` with the same entries (ELL padding: repeated positions holding 0)."""
        indices = jnp.stack([self.pattern.rows, self.pattern.cols], axis=1)
        return jsparse.BCOO((self.values, indices), shape=self.shape)

    def to_scipy(self) -> sp.csr_matrix:
        """Host copy as a canonical `scipy.sparse.csr_matrix` (sorted indices, padding merged away)."""
        values = np.asarray(self.values)
        rows, cols = np.asarray(self.pattern.rows), np.asarray(self.pattern.cols)
        if self.pattern.layout == "csr":
            return sp.csr_matrix((values, cols, np.asarray(self.pattern.indptr)), shape=self.shape)
        matrix = sp.csr_matrix((values, (rows, cols)), shape=self.shape)
        matrix.sum_duplicates()
        return matrix

    def as_lineax_operator(
        self, *, symmetric: bool = False, positive_semidefinite: bool = False, negative_semidefinite: bool = False
    ) -> lx.FunctionLinearOperator:
        """`x -> A @ x` as a lineax operator on `(n_cols,)` vectors, with the tags the caller vouches for.

        Tag `symmetric=True, positive_semidefinite=True` for the cotan Laplacian and the mass matrices
        (lineax's `CG` needs a (semi)definite tag; the tags are promises, not checked). Without the
        symmetric tag lineax transposes with `jax.linear_transpose`.
        """
        tags = []
        if symmetric:
            tags.append(lx.symmetric_tag)
        if positive_semidefinite:
            tags.append(lx.positive_semidefinite_tag)
        if negative_semidefinite:
            tags.append(lx.negative_semidefinite_tag)
        structure = jax.ShapeDtypeStruct((self.shape[1],), self.values.dtype)
        return lx.FunctionLinearOperator(self.__matmul__, structure, tuple(tags))


def diagonal_matrix(values: Float[Array, " n"]) -> SparseMatrix:
    """Diagonal `SparseMatrix` (Hodge stars, lumped mass): `A @ x = values * x`, `A.T = A`."""
    return SparseMatrix(values, SparsityPattern.diagonal(values.shape[0]))


def from_scipy(matrix: sp.spmatrix) -> SparseMatrix:
    """`SparseMatrix` (host-built ELL pattern) with the entries of a SciPy sparse matrix (duplicates summed)."""
    coo = sp.coo_matrix(matrix)
    pattern, slot = SparsityPattern.from_coo(coo.row, coo.col, coo.shape)
    values = np.zeros(pattern.nnz, dtype=coo.data.dtype)
    np.add.at(values, slot, coo.data)
    return SparseMatrix(jnp.asarray(values), pattern)


def _broadcast(values: Float[Array, " m"], x: Float[Array, "n *batch"]) -> Float[Array, " m *ones"]:
    return values.reshape(values.shape + (1,) * (x.ndim - 1))


def _coo_transpose(matrix: SparseMatrix) -> SparseMatrix:
    """Transpose of a `"csr"` pattern built without host data (e.g. inside jit): swap rows and columns.

    The only place a sort runs inside jit (a stable argsort of the column indices); host-built
    patterns carry their transpose instead (`SparsityPattern.transpose_slot`).
    """
    pattern = matrix.pattern
    n_rows, n_cols = pattern.shape
    counts = jnp.zeros(n_cols + 1, pattern.indptr.dtype).at[pattern.cols + 1].add(1)
    order = jnp.argsort(pattern.cols, stable=True)
    transposed = SparsityPattern(
        rows=pattern.cols[order], cols=pattern.rows[order], indptr=jnp.cumsum(counts), shape=(n_cols, n_rows)
    )
    return SparseMatrix(matrix.values[order], transposed)


def _check_same_pattern(a: SparseMatrix, b: SparseMatrix, op: str) -> None:
    if not isinstance(b, SparseMatrix):
        raise DDGInputError(f"other: SparseMatrix {op} needs another SparseMatrix, got {type(b).__name__}")
    pa, pb = a.pattern, b.pattern
    if pa is pb:
        return
    static_a = (pa.shape, pa.layout, pa.width, pa.diagonal_first, pa.nnz)
    static_b = (pb.shape, pb.layout, pb.width, pb.diagonal_first, pb.nnz)
    if static_a != static_b:
        raise DDGInputError(
            f"A {op} B needs matching sparsity patterns; got shape/layout/width/nnz {static_a} and {static_b} "
            "(add matrices assembled on the same pattern, e.g. cotan_laplacian and mass_matrix(kind='galerkin'))"
        )
    for name in ("rows", "cols"):
        x, y = getattr(pa, name), getattr(pb, name)
        if x is y:
            continue
        if is_traced(x) or is_traced(y):
            raise DDGInputError(
                f"A {op} B: cannot verify under jit that two different pattern arrays ({name}) match; pass "
                "matrices that share one pattern object (e.g. both built from the same mesh)"
            )
        mismatch = np.flatnonzero(np.asarray(x) != np.asarray(y))
        if mismatch.size:
            raise DDGInputError(f"A {op} B needs matching sparsity patterns; {name} differ first at slot {int(mismatch[0])}")
