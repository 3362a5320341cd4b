"""`SparseMatrix`: values on a fixed `SparsityPattern`, differentiable through its values."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import scipy.sparse as sp
from jax.experimental import sparse as jsparse
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, is_traced
from .._indexing import take_rows, take_rows_or_zero
from ._pattern import SparsityPattern


class SparseMatrix(eqx.Module):
    """A sparse matrix whose nonzero *positions* are fixed and whose *values* are JAX arrays.

    The pattern comes from the topology once; new geometry only re-assembles `values`, so every
    function of the values (products, solves, energies) is jit-compiled once and differentiable
    (`jax.grad` / `jax.jvp` / `jax.vmap` through `values` and through the right-hand side).

    Arithmetic: `A @ x` (`x` of shape `(n_cols,)` or `(n_cols, k)`), `A.T`, `A + B`, `A - B`, `-A`,
    `c * A`, `A / c`, `A.diagonal()`, `A.row_sums()`; exports `todense()`, `to_scipy()`, `to_bcoo()`,
    `as_lineax_operator()`. `A + B` needs one pattern for both, or one of them diagonal (a lumped
    mass matrix or Hodge star) and the other square with its diagonal stored: the result lives on the
    larger pattern, so `M + t L` and `M - t L` (heat method, implicit mean curvature flow) work.

    Structure flags (static): `symmetric`, `positive_semidefinite`, `negative_semidefinite` are
    promises about the values, set by the constructors that can prove them (`cotan_laplacian` and
    `mass_matrix` are symmetric PSD; a diagonal matrix is symmetric; `from_scipy` checks symmetry)
    and carried through arithmetic while they stay provable: `A + B` keeps what both have, `-A` swaps
    the two semidefinite flags, `c * A` keeps them for a concrete `c >= 0` and swaps them for
    `c <= 0`; a traced `c` (inside jit) cannot be checked, so only `symmetric` survives. The flags
    become lineax tags in `as_lineax_operator()`, so `lineax.CG` accepts `M + t L` as it is. Assert a
    flag that holds but cannot be proven with `dataclasses.replace(A, positive_semidefinite=True)` or
    the keywords of `as_lineax_operator`. A semidefinite flag implies `symmetric` (as in lineax).

    Attributes:
        values: `(nnz,)` entries in the pattern's storage order (see `SparsityPattern`; padding slots
            of an ELL pattern hold 0).
        pattern: the `SparsityPattern`.
        symmetric: `A == A.T` (static).
        positive_semidefinite: symmetric and `x^T A x >= 0` for every `x` (static).
        negative_semidefinite: symmetric and `x^T A x <= 0` for every `x` (static).
    """

    values: Float[Array, " nnz"] = eqx.field(converter=jnp.asarray)
    pattern: SparsityPattern
    symmetric: bool = eqx.field(static=True, default=False)
    positive_semidefinite: bool = eqx.field(static=True, default=False)
    negative_semidefinite: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if self.values.shape != (self.pattern.nnz,):
            raise DDGInputError(f"values: expected shape ({self.pattern.nnz},) (the pattern's nnz), got {self.values.shape}")
        if (self.positive_semidefinite or self.negative_semidefinite) and not self.symmetric:
            raise DDGInputError("symmetric: a semidefinite SparseMatrix must also be flagged symmetric")
        if self.symmetric and self.pattern.shape[0] != self.pattern.shape[1]:
            raise DDGInputError(f"symmetric: a symmetric matrix must be square, got shape {self.pattern.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    @property
    def dtype(self):
        return self.values.dtype

    def __matmul__(self, x: Float[ArrayLike, "n_cols *batch"]) -> Float[Array, "n_rows *batch"]:
        """`A @ x` for a vector `(n_cols,)` or a block of right-hand sides `(n_cols, k)`."""
        n_cols = self.shape[1]
        if isinstance(x, (SparseMatrix, jsparse.JAXSparse)) or sp.issparse(x):
            raise DDGInputError(
                f"x: sparse-sparse products are not supported (A @ B with B a {type(x).__name__}); multiply by a "
                "dense (n_cols,) vector or (n_cols, k) block, or multiply the exports: A.to_scipy() @ B.to_scipy()"
            )
        if np.ndim(x) not in (1, 2) or np.shape(x)[0] != n_cols:  # shapes are known under jit too
            raise DDGInputError(f"x: expected shape ({n_cols},) or ({n_cols}, k), got {np.shape(x)}")
        x = jnp.asarray(x)
        if is_traced(x) or is_traced(self.values) or is_traced(self.pattern.cols):
            return self._product(x)
        # Eager: one compiled program (cached per shape and pattern layout) instead of a dozen dispatches.
        return _compiled_product(self, x)

    def __array__(self, *args, **kwargs):
        raise DDGInputError(
            "A: a SparseMatrix is not a dense array; use A.todense() (small matrices, tests), A.to_scipy() or "
            "A.to_bcoo(), or A @ x for products"
        )

    def _product(self, x: Float[Array, "n_cols *batch"]) -> Float[Array, "n_rows *batch"]:
        pattern = self.pattern
        if pattern.layout != "ell":
            products = _broadcast(self.values, x) * x[pattern.cols]
            return jax.ops.segment_sum(
                products, pattern.rows, num_segments=self.shape[0], indices_are_sorted=pattern.layout == "csr"
            )
        index = pattern.row_cols
        if index is None:  # an ELL pattern assembled by hand: transpose the index here
            n_rows, width = self.shape[0], pattern.width
            index = pattern.cols[: n_rows * width].reshape(width, n_rows)[int(pattern.diagonal_first) :].T
        return _ell_product(self.values, index, _tail(pattern), x, self.shape[0], pattern.width, pattern.diagonal_first)

    @property
    def T(self) -> "SparseMatrix":
        """Transpose, without any sort or search inside jit.

        A symmetric matrix is its own transpose; on a host-built pattern the values are permuted by
        the precomputed `transpose_slot` (one gather); otherwise rows and columns swap and the values
        stay where they are (a `"coo"` pattern: products become an unsorted `segment_sum`).
        """
        pattern = self.pattern
        flags = _flags(self)
        if self.symmetric or pattern.is_diagonal:
            return self
        if pattern.symmetric and pattern.transpose_slot is not None:
            return SparseMatrix(take_rows(self.values, pattern.transpose_slot), pattern, **flags)
        if pattern.transpose_pattern is not None:
            values = take_rows_or_zero(self.values, pattern.transpose_slot)
            return SparseMatrix(values, pattern.transpose_pattern, **flags)
        swapped = SparsityPattern(rows=pattern.cols, cols=pattern.rows, indptr=None, shape=pattern.shape[::-1], layout="coo")
        return SparseMatrix(self.values, swapped, **flags)

    def __add__(self, other: "SparseMatrix") -> "SparseMatrix":
        return _add(self, other, 1.0)

    def __sub__(self, other: "SparseMatrix") -> "SparseMatrix":
        return _add(self, other, -1.0)

    def __neg__(self) -> "SparseMatrix":
        return _scaled(self, -self.values, -1.0)

    def __mul__(self, scalar) -> "SparseMatrix":
        if isinstance(scalar, SparseMatrix) or np.ndim(scalar) != 0:
            raise DDGInputError(
                f"scalar: SparseMatrix * c needs a scalar c (use A @ x for products), got shape {np.shape(scalar)}"
            )
        return _scaled(self, self.values * scalar, scalar)

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
        if pattern.layout != "ell":
            return jax.ops.segment_sum(self.values, pattern.rows, num_segments=n_rows, indices_are_sorted=pattern.layout == "csr")
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
        self,
        *,
        symmetric: bool | None = None,
        positive_semidefinite: bool | None = None,
        negative_semidefinite: bool | None = None,
    ) -> lx.FunctionLinearOperator:
        """`x -> A @ x` as a lineax operator on `(n_cols,)` vectors, tagged from the structure flags.

        By default the tags are the matrix's own flags (`symmetric_tag`, `positive_semidefinite_tag`,
        `negative_semidefinite_tag`), so `cotan_laplacian(m)`, `mass_matrix(m)` and `M + t L` (concrete
        `t >= 0`) go straight into `lineax.CG`. A keyword overrides a flag (`True` is a promise, not
        checked; e.g. `positive_semidefinite=True` for `M + t L` with `t` traced under jit). Without a
        symmetric tag lineax transposes with `jax.linear_transpose`. The operator is differentiable
        through `values` (e.g. `jax.grad` of a `lineax.linear_solve` with respect to vertex positions).

        SciPy equivalent: `scipy.sparse.linalg.aslinearoperator(A.to_scipy())`.
        """
        flags = {
            "symmetric": self.symmetric if symmetric is None else symmetric,
            "positive_semidefinite": self.positive_semidefinite if positive_semidefinite is None else positive_semidefinite,
            "negative_semidefinite": self.negative_semidefinite if negative_semidefinite is None else negative_semidefinite,
        }
        tags = [
            tag
            for flag, tag in (
                ("symmetric", lx.symmetric_tag),
                ("positive_semidefinite", lx.positive_semidefinite_tag),
                ("negative_semidefinite", lx.negative_semidefinite_tag),
            )
            if flags[flag]
        ]
        structure = jax.ShapeDtypeStruct((self.shape[1],), self.values.dtype)
        return lx.FunctionLinearOperator(self.__matmul__, structure, tuple(tags))


def diagonal_matrix(values: Float[ArrayLike, " n"], *, positive_semidefinite: bool = False) -> SparseMatrix:
    """Diagonal `SparseMatrix` (Hodge stars, lumped mass): `A @ x = values * x`, `A.T = A`.

    Flagged symmetric; `positive_semidefinite=True` is the caller's promise that `values >= 0`.
    SciPy: `scipy.sparse.diags(values)`.
    """
    values = jnp.asarray(values)
    if values.ndim != 1:
        raise DDGInputError(f"values: expected shape (n,), got {values.shape}")
    return SparseMatrix(
        values, SparsityPattern.diagonal(values.shape[0]), symmetric=True, positive_semidefinite=positive_semidefinite
    )


def from_scipy(matrix: sp.spmatrix, *, positive_semidefinite: bool = False) -> SparseMatrix:
    """`SparseMatrix` (host-built ELL pattern) with the entries of a SciPy sparse matrix (duplicates summed).

    `symmetric` is set when the matrix equals its transpose exactly (checked on the host);
    `positive_semidefinite=True` is the caller's promise (needs a symmetric matrix).
    """
    coo = sp.coo_matrix(matrix)
    pattern, slot = SparsityPattern.from_coo(coo.row, coo.col, coo.shape)
    values = np.zeros(pattern.nnz, dtype=coo.data.dtype)
    np.add.at(values, slot, coo.data)
    csr = coo.tocsr()
    symmetric = csr.shape[0] == csr.shape[1] and (csr != csr.T).nnz == 0
    if positive_semidefinite and not symmetric:
        raise DDGInputError("positive_semidefinite: the matrix is not symmetric, so it cannot be flagged semidefinite")
    return SparseMatrix(jnp.asarray(values), pattern, symmetric=symmetric, positive_semidefinite=positive_semidefinite)


def _broadcast(values: Float[Array, " m"], x: Float[Array, "n *batch"]) -> Float[Array, " m *ones"]:
    return values.reshape(values.shape + (1,) * (x.ndim - 1))


def _flags(matrix: SparseMatrix) -> dict:
    return {
        "symmetric": matrix.symmetric,
        "positive_semidefinite": matrix.positive_semidefinite,
        "negative_semidefinite": matrix.negative_semidefinite,
    }


def _scaled(matrix: SparseMatrix, values: Float[Array, " nnz"], scalar) -> SparseMatrix:
    """`matrix` with new `values = scalar * matrix.values`: semidefinite flags follow the sign of a concrete scalar."""
    psd, nsd = matrix.positive_semidefinite, matrix.negative_semidefinite
    sign = None if is_traced(scalar) or np.iscomplexobj(scalar) else float(np.asarray(scalar))
    if sign is None or np.isnan(sign):
        psd = nsd = False
    elif sign == 0:
        psd = nsd = matrix.symmetric
    elif sign < 0:
        psd, nsd = nsd, psd
    return SparseMatrix(values, matrix.pattern, symmetric=matrix.symmetric, positive_semidefinite=psd, negative_semidefinite=nsd)


def _add(a: SparseMatrix, b: SparseMatrix, sign: float) -> SparseMatrix:
    """`a + sign * b` on the larger of the two patterns (equal patterns, or one of them diagonal)."""
    op = "+" if sign > 0 else "-"
    if not isinstance(b, SparseMatrix):
        raise DDGInputError(f"other: SparseMatrix {op} needs another SparseMatrix, got {type(b).__name__}")
    if a.shape != b.shape:
        raise DDGInputError(f"A {op} B needs equal shapes, got {a.shape} and {b.shape}")
    if _same_positions(a.pattern, b.pattern, op):
        values, pattern = a.values + sign * b.values, a.pattern
    elif b.pattern.is_diagonal:
        values, pattern = _add_to_diagonal(a.values, a.pattern, sign * b.values, op), a.pattern
    elif a.pattern.is_diagonal:
        values, pattern = _add_to_diagonal(sign * b.values, b.pattern, a.values, op), b.pattern
    else:
        raise DDGInputError(
            f"A {op} B needs matching sparsity patterns (or one diagonal); got shape/layout/width/nnz "
            f"{_static(a.pattern)} and {_static(b.pattern)} (add matrices assembled on the same pattern, "
            "e.g. cotan_laplacian and mass_matrix)"
        )
    b_psd, b_nsd = b.positive_semidefinite, b.negative_semidefinite
    if sign < 0:  # -B swaps the two semidefinite flags
        b_psd, b_nsd = b_nsd, b_psd
    return SparseMatrix(
        values,
        pattern,
        symmetric=a.symmetric and b.symmetric,
        positive_semidefinite=a.positive_semidefinite and b_psd,
        negative_semidefinite=a.negative_semidefinite and b_nsd,
    )


def _add_to_diagonal(values, pattern: SparsityPattern, diagonal, op: str):
    """`values` of a square matrix on `pattern` plus `diagonal` on its main diagonal (no search, no scatter)."""
    n = pattern.shape[0]
    if pattern.diagonal_first:
        return values.at[:n].add(diagonal)  # slots 0..n-1 are the diagonal
    if pattern.layout == "csr":  # distinct entries: exactly one slot per diagonal position
        on_diagonal = pattern.rows == pattern.cols
        if not (is_traced(pattern.rows) or is_traced(pattern.cols)):
            missing = np.setdiff1d(np.arange(n), np.asarray(pattern.rows)[np.asarray(on_diagonal)])
            if missing.size:
                raise DDGInputError(
                    f"A {op} D: the pattern lacks diagonal entries (first at row {int(missing[0])}), so a diagonal "
                    "matrix cannot be added onto it"
                )
        else:
            values = eqx.error_if(values, jnp.sum(on_diagonal) != n, f"A {op} D: the pattern lacks diagonal entries")
        return values + jnp.where(on_diagonal, diagonal[pattern.rows], 0)
    raise DDGInputError(
        f"A {op} D: adding a diagonal matrix needs a pattern that stores the whole diagonal (a host-built "
        f"square pattern with every diagonal entry, or a CSR pattern); got layout {pattern.layout!r} with "
        f"diagonal_first={pattern.diagonal_first}"
    )


_compiled_product = jax.jit(SparseMatrix._product)


def _tail(pattern: SparsityPattern) -> tuple[Int[Array, " nnz"], Int[Array, " nnz"]] | None:
    """`(rows, cols)` of an ELL pattern with a COO tail (sliced inside the product), else `None`."""
    return (pattern.rows, pattern.cols) if pattern.nnz > pattern.shape[0] * pattern.width else None


def _ell_product(values, index, tail, x, n_rows: int, width: int, diagonal_first: bool):
    """`A @ x` on an ELL(+COO tail) pattern (`SparsityPattern`), from the arrays it reads.

    `index` is the `(n_rows, width - first)` row-major column index (`SparsityPattern.row_cols`): one
    gather of every row's columns, row by row, then `width` contiguous multiply-adds fused into one
    pass. One row-major gather (rather than one gather per ELL block) keeps the product fast whatever
    the vertex order of the mesh. The diagonal block of a diagonal-first pattern multiplies `x` itself.
    """
    ell_values = values[: n_rows * width].reshape(width, n_rows)
    first = 1 if diagonal_first else 0
    if width > first:
        gathered = take_rows(x, index)
    result = _broadcast(ell_values[0], x) * (x if first else gathered[:, 0])
    for k in range(1, width):
        result = result + _broadcast(ell_values[k], x) * gathered[:, k - first]
    if tail is not None:
        rows, cols = (array[n_rows * width :] for array in tail)
        result = result + jax.ops.segment_sum(
            _broadcast(values[n_rows * width :], x) * take_rows(x, cols), rows, num_segments=n_rows, indices_are_sorted=True
        )
    return result


def _static(pattern: SparsityPattern) -> tuple:
    return (pattern.shape, pattern.layout, pattern.width, pattern.diagonal_first, pattern.nnz)


def _same_positions(pa: SparsityPattern, pb: SparsityPattern, op: str) -> bool:
    """Do two patterns store the same positions in the same order? Raises where that cannot be decided."""
    if pa is pb or (pa.is_diagonal and pb.is_diagonal and pa.shape == pb.shape):
        return True
    if _static(pa) != _static(pb):
        return False
    for name in ("rows", "cols"):
        x, y = getattr(pa, name), getattr(pb, name)
        if x is y:
            continue
        if is_traced(x) or is_traced(y):
            raise DDGInputError(
                f"A {op} B: cannot verify under jit that two different pattern arrays ({name}) match; pass "
                "matrices that share one pattern object (e.g. both built from the same mesh)"
            )
        if not np.array_equal(np.asarray(x), np.asarray(y)):
            return False
    return True
