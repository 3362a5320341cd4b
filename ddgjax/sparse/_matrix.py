"""`SparseMatrix`: values on a fixed `SparsityPattern`, differentiable through its values."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, ArrayLike, Float, Inexact, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_count, is_traced
from .._indexing import take_rows, take_rows_or_zero
from .._results import RESULTS, raise_if_failed
from ._nonnegative import NonNegative
from ._pattern import SparsityPattern

if TYPE_CHECKING:  # imported where used: lineax and jax.experimental.sparse add to every `import ddgjax.mesh`
    import lineax as lx
    from jax.experimental import sparse as jsparse


class SparseMatrix(eqx.Module):
    """A sparse matrix whose nonzero *positions* are fixed and whose *values* are JAX arrays.

    The pattern comes from the topology once; new geometry only re-assembles `values`, so every
    function of the values (products, solves, energies) is jit-compiled once and differentiable
    (`jax.grad` / `jax.jvp` / `jax.vmap` through `values` and through the right-hand side).

    Values may be real or complex (a complex connection Laplacian, for direction fields).

    Arithmetic: `A @ x` (`x` of shape `(n_cols,)` or `(n_cols, k)`, real or complex), `A.T`,
    `A.conj()`, `A.H` (`conj(A).T`), `A + B`, `A - B`, `-A`, `c * A`, `A / c`, `A.shifted(s)`
    (`A + s I`), `A.diagonal()`, `A.row_sums()`, `A.nnz`; exports
    `todense()`, `to_scipy()`, `to_bcoo()`, `as_lineax_operator()`. `A + B` needs one pattern for
    both, or one of them diagonal (a lumped mass matrix, a Hodge star, `identity(n)`) and the other
    square with its diagonal stored: the result lives on the larger pattern, so `M + t L` and
    `M - t L` (heat method, implicit mean curvature flow) and `A + s * identity(n)` work.

    Structure flags (static): `symmetric`, `hermitian`, `positive_semidefinite`, `negative_semidefinite`
    are promises about the values, set by the constructors that can prove them (`cotan_laplacian` and
    `mass_matrix` are symmetric PSD; a diagonal matrix is symmetric; `from_scipy` checks symmetry)
    and carried through arithmetic while they stay provable: `A + B` keeps what both have, `-A` swaps
    the two semidefinite flags, `c * A` keeps them for a concrete `c >= 0` and swaps them for
    `c <= 0`. A traced `c` (inside jit) has no value to look at, so only `symmetric` (and `hermitian`
    for a real `c`) survives, unless it is declared non-negative: `nonnegative(t) * A` keeps the flags and checks `t >= 0`
    when the program runs. The flags become lineax tags in `as_lineax_operator()`, so `lineax.CG`
    accepts `M + t L` (concrete `t >= 0`) and `M + nonnegative(t) * L` (any `t`) as they are. Assert
    a flag that holds but cannot be proven with `dataclasses.replace(A, positive_semidefinite=True)`
    or the keywords of `as_lineax_operator`.

    Complex matrices: `symmetric` is `A == A.T` and `hermitian` is `A == conj(A).T`; a complex
    semidefinite matrix is Hermitian (`x^H A x` real for every `x` only then), so on a complex matrix
    a semidefinite flag needs `hermitian`. For a real matrix the two are the same property: a real
    matrix flagged `symmetric` counts as Hermitian (`hermitian` need not be set, and real constructors
    do not set it) and a semidefinite flag needs either. `A.self_adjoint` (`A == A^H`) reads that rule.
    `hermitian` is carried like the others: `A + B` keeps it when both are self-adjoint (a real
    symmetric `M` plus a complex Hermitian `L` is complex Hermitian, so `M + t L` stays Hermitian PSD),
    `-A` keeps it, `c * A`, `A / c` and `A.shifted(c)` keep it for a real `c` (a concrete real, a traced
    real dtype, or `nonnegative(t)`) and drop it for a complex `c`; the semidefinite flags of a complex
    Hermitian matrix follow the sign rules above. `from_scipy` sets `hermitian` for a complex matrix
    equal to its conjugate transpose.

    Attributes:
        values: `(nnz,)` entries in the pattern's storage order (see `SparsityPattern`; padding slots
            of an ELL pattern hold 0).
        pattern: the `SparsityPattern`.
        symmetric: `A == A.T` (static).
        positive_semidefinite: self-adjoint and `x^H A x >= 0` for every `x` (static).
        negative_semidefinite: self-adjoint and `x^H A x <= 0` for every `x` (static).
        hermitian: `A == conj(A).T` (static); for real values the same as `symmetric` (`self_adjoint`).
    """

    values: Inexact[Array, " nnz"] = eqx.field(converter=device_array)
    pattern: SparsityPattern
    symmetric: bool = eqx.field(static=True, default=False)
    positive_semidefinite: bool = eqx.field(static=True, default=False)
    negative_semidefinite: bool = eqx.field(static=True, default=False)
    hermitian: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if self.values.shape != (self.pattern.nnz,):
            raise DDGInputError(f"values: expected shape ({self.pattern.nnz},) (the pattern's nnz), got {self.values.shape}")
        if (self.symmetric or self.hermitian) and self.pattern.shape[0] != self.pattern.shape[1]:
            name = "symmetric" if self.symmetric else "hermitian"
            raise DDGInputError(f"{name}: a {name} matrix must be square, got shape {self.pattern.shape}")
        if (self.positive_semidefinite or self.negative_semidefinite) and not self.self_adjoint:
            if _is_complex(self.values):
                raise DDGInputError(
                    "hermitian: a complex semidefinite SparseMatrix must also be flagged hermitian (A == conj(A).T; "
                    "symmetric, A == A.T, is not enough for complex values)"
                )
            raise DDGInputError("symmetric: a semidefinite SparseMatrix must also be flagged symmetric")

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    @property
    def dtype(self):
        return self.values.dtype

    @property
    def self_adjoint(self) -> bool:
        """`A == A^H` as the flags prove it (static): `hermitian`, or `symmetric` with real values.

        For real values Hermitian and symmetric are the same property, so a real matrix flagged either
        way is self-adjoint; a complex matrix only when flagged `hermitian` (a complex symmetric matrix,
        `A == A.T`, is not). What a linear solve needs: a semidefinite flag implies it.
        """
        return self.hermitian or (self.symmetric and not _is_complex(self.values))

    @property
    def nnz(self) -> int:
        """Number of stored entries as SciPy counts them: distinct positions, ELL padding excluded.

        `A.nnz == A.to_scipy().nnz` (explicitly stored zeros count, as in SciPy), while
        `A.pattern.nnz >= A.nnz` is the storage length, `A.values.shape[0]`, padding included. A
        static count: host-built patterns (`from_coo`, `from_edges`, `diagonal`, so every matrix
        from `cotan_laplacian`, `mass_matrix`, `from_scipy`) carry it, so it is known under jit too;
        a `"csr"` pattern stores each position once, so it is its length. Only for an ELL / COO
        pattern made by hand is it counted on the host from the pattern arrays, which needs them
        concrete (`DDGInputError` under jit when they are traced).
        """
        pattern = self.pattern
        if pattern.n_entries is not None:
            return pattern.n_entries
        if pattern.layout == "csr":
            return pattern.nnz
        return int(pattern.entries()[0].size)

    def __matmul__(self, x: Inexact[ArrayLike, "n_cols *batch"]) -> Inexact[Array, "n_rows *batch"]:
        """`A @ x` for a vector `(n_cols,)` or a block of right-hand sides `(n_cols, k)`.

        Real or complex `A` and `x`; the result has JAX's promoted dtype (complex if either is).
        """
        n_cols = self.shape[1]
        if isinstance(x, SparseMatrix) or _is_jax_sparse(x) or sp.issparse(x):
            raise DDGInputError(
                f"x: sparse-sparse products are not supported (A @ B with B a {type(x).__name__}); multiply by a "
                "dense (n_cols,) vector or (n_cols, k) block, or multiply the exports: A.to_scipy() @ B.to_scipy()"
            )
        if np.ndim(x) not in (1, 2) or np.shape(x)[0] != n_cols:  # shapes are known under jit too
            raise DDGInputError(f"x: expected shape ({n_cols},) or ({n_cols}, k), got {np.shape(x)}")
        x = device_array(x)
        if is_traced(x) or is_traced(self.values) or is_traced(self.pattern.cols):
            return self._product(x)
        # Eager: one compiled program (cached per shape and pattern layout) instead of a dozen dispatches.
        return _compiled_product(self, x)

    def __array__(self, *args, **kwargs):
        raise DDGInputError(
            "A: a SparseMatrix is not a dense array; use A.todense() (small matrices, tests), A.to_scipy() or "
            "A.to_bcoo(), or A @ x for products"
        )

    def _product(self, x: Inexact[Array, "n_cols *batch"]) -> Inexact[Array, "n_rows *batch"]:
        pattern = self.pattern
        x = _stored(x)
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
        """Transpose (not conjugated; `A.H` is the conjugate transpose), without any sort or search inside jit.

        A symmetric matrix (and a real one flagged `hermitian`) is its own transpose; a complex
        Hermitian matrix's transpose is `conj(A)`, its values conjugated on the same pattern. On a
        host-built pattern the values are permuted by the precomputed `transpose_slot` (one gather);
        otherwise rows and columns swap and the values stay where they are (a `"coo"` pattern: products
        become an unsorted `segment_sum`).
        """
        pattern = self.pattern
        flags = _flags(self)
        if self.symmetric or pattern.is_diagonal:
            return self
        if self.hermitian:  # A.T = conj(A.H) = conj(A); for real values conj(A) = A
            return self.conj()
        if pattern.symmetric and pattern.transpose_slot is not None:
            return SparseMatrix(take_rows(self.values, pattern.transpose_slot), pattern, **flags)
        if pattern.transpose_pattern is not None:
            values = take_rows_or_zero(self.values, pattern.transpose_slot)
            return SparseMatrix(values, pattern.transpose_pattern, **flags)
        swapped = SparsityPattern(
            rows=pattern.cols,
            cols=pattern.rows,
            indptr=None,
            shape=pattern.shape[::-1],
            layout="coo",
            n_entries=pattern.nnz if pattern.layout == "csr" else pattern.n_entries,
        )
        return SparseMatrix(self.values, swapped, **flags)

    def conj(self) -> "SparseMatrix":
        """Complex conjugate `conj(A)`: the values conjugated on the same pattern, flags kept.

        (`conj(A)` is symmetric / Hermitian / semidefinite exactly when `A` is.) A real matrix is
        returned as it is. NumPy / SciPy: `A.conj()`.
        """
        if not _is_complex(self.values):
            return self
        return SparseMatrix(jnp.conj(self.values), self.pattern, **_flags(self))

    @property
    def H(self) -> "SparseMatrix":
        """Conjugate transpose `conj(A).T`: `A` itself when self-adjoint (`self_adjoint`), else `A.T.conj()`.

        SciPy: `A.conj().T` (`A.getH()`).
        """
        if self.self_adjoint:
            return self
        return self.T.conj()

    def __add__(self, other: "SparseMatrix") -> "SparseMatrix":
        return _add(self, other, 1.0)

    def __sub__(self, other: "SparseMatrix") -> "SparseMatrix":
        return _add(self, other, -1.0)

    def __neg__(self) -> "SparseMatrix":
        return _scaled(self, _times(self.values, -1.0), -1.0)

    def __mul__(self, scalar) -> "SparseMatrix":
        if isinstance(scalar, NonNegative):
            return _scaled(self, _times(self.values, scalar.value), scalar)
        if isinstance(scalar, SparseMatrix) or np.ndim(scalar) != 0:
            raise DDGInputError(
                f"scalar: SparseMatrix * c needs a scalar c (use A @ x for products), got shape {np.shape(scalar)}"
            )
        return _scaled(self, _times(self.values, scalar), scalar)

    __rmul__ = __mul__

    def __truediv__(self, scalar) -> "SparseMatrix":
        if isinstance(scalar, NonNegative):  # 1 / t >= 0 for t >= 0 (inf at 0, as for a plain scalar)
            return self * NonNegative(1.0 / scalar.value)
        return self * (1.0 / scalar)

    def shifted(self, shift) -> "SparseMatrix":
        """`A + shift * I` on the same pattern: one add on the stored diagonal.

        For a square matrix whose pattern stores the whole diagonal (every host-built square pattern
        with its diagonal, e.g. `cotan_laplacian`, `mass_matrix`, `from_scipy(A + eye)`, or a CSR
        pattern holding it); otherwise `DDGInputError`. On a diagonal-first pattern it adds to the
        first `n` slots. Flags: `symmetric` is kept; `hermitian` is kept for a real `shift` (a complex
        one makes a real matrix complex and drops it); `positive_semidefinite` is kept when `shift` is
        provably `>= 0` (a concrete real number, or `nonnegative(s)` for a traced one), and
        `negative_semidefinite` when it is provably `<= 0`. Differentiable in the values and in
        `shift`. SciPy: `A + shift * scipy.sparse.identity(n)`; the same as `A + shift * identity(n)`.

        Args:
            shift: a scalar, `()` (real or complex), or `nonnegative(s)`.

        Returns:
            `(n, n)` `SparseMatrix` on `A.pattern`.
        """
        value = shift.value if isinstance(shift, NonNegative) else shift
        if isinstance(value, SparseMatrix) or np.ndim(value) != 0:
            raise DDGInputError(f"shift: A.shifted(s) needs a scalar s, got shape {np.shape(value)}")
        n_rows, n_cols = self.shape
        if n_rows != n_cols:
            raise DDGInputError(f"A: A.shifted(s) needs a square matrix, got shape {self.shape}")
        values = self.values
        if np.iscomplexobj(value) and not _is_complex(values):  # a complex shift makes the matrix complex
            values = values.astype(jnp.result_type(values, value))
        values = _add_to_diagonal(values, self.pattern, jnp.asarray(value, values.dtype), "A.shifted(s)")
        at_least_zero, at_most_zero = _sign_bounds(shift)
        real = _is_real_scalar(shift)
        return SparseMatrix(
            values,
            self.pattern,
            symmetric=self.symmetric or (_real_hermitian(self) and not real),  # real Hermitian + complex s I: symmetric
            positive_semidefinite=self.positive_semidefinite and at_least_zero,
            negative_semidefinite=self.negative_semidefinite and at_most_zero,
            hermitian=self.hermitian and real,
        )

    def diagonal(self) -> Inexact[Array, " n"]:
        """The main diagonal, `(min(n_rows, n_cols),)` (zeros where the pattern has no diagonal entry)."""
        pattern = self.pattern
        n = min(self.shape)
        if pattern.diagonal_first:
            return self.values[:n]
        on_diagonal = pattern.rows == pattern.cols
        return jax.ops.segment_sum(jnp.where(on_diagonal, self.values, 0), jnp.where(on_diagonal, pattern.rows, n), n)

    def row_sums(self) -> Inexact[Array, " n_rows"]:
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

    def todense(self) -> Inexact[Array, "n_rows n_cols"]:
        """Dense copy (for tests and small problems)."""
        return jnp.zeros(self.shape, self.values.dtype).at[self.pattern.rows, self.pattern.cols].add(self.values)

    def to_bcoo(self) -> jsparse.BCOO:
        """`jax.experimental.sparse.BCOO` with the same entries (ELL padding: repeated positions holding 0)."""
        from jax.experimental import sparse as jsparse

        indices = jnp.stack([self.pattern.rows, self.pattern.cols], axis=1)
        return jsparse.BCOO((self.values, indices), shape=self.shape)

    def to_scipy(self) -> sp.csr_matrix:
        """Host copy as a canonical `scipy.sparse.csr_matrix` (sorted indices, padding left out; `nnz == A.nnz`)."""
        values = np.asarray(self.values)
        if self.pattern.layout == "csr":
            cols = np.asarray(self.pattern.cols)
            return sp.csr_matrix((values, cols, np.asarray(self.pattern.indptr)), shape=self.shape)
        rows, cols = np.asarray(self.pattern.rows), np.asarray(self.pattern.cols)
        if self.pattern.layout == "ell" and self.pattern.indptr is not None:
            # The padding of an empty row sits at (i, 0), a position the row does not hold.
            empty_rows = np.diff(np.asarray(self.pattern.indptr)) == 0
            if empty_rows.any():
                keep = ~empty_rows[rows]
                values, rows, cols = values[keep], rows[keep], cols[keep]
        matrix = sp.csr_matrix((values, (rows, cols)), shape=self.shape)
        matrix.sum_duplicates()  # merges padding into the real entry it repeats (padding holds 0)
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
        `t >= 0`) go straight into `lineax.CG`. lineax's `symmetric_tag` means `A == A.T` also for
        complex values: a real matrix flagged `symmetric` or `hermitian` gets it, a complex one only
        when flagged `symmetric` (a complex Hermitian matrix does not), while the semidefinite tags
        (which lineax reads as Hermitian semidefinite for complex operators) follow the flags, so a
        complex Hermitian PSD matrix (a connection Laplacian, `M + t L`) goes into `lineax.CG` too. A keyword overrides a flag (`True` is a promise, not
        checked; e.g. `positive_semidefinite=True` for `M + t L` with `t` traced under jit). Without a
        symmetric tag lineax transposes with `jax.linear_transpose`. The operator is differentiable
        through `values` (e.g. `jax.grad` of a `lineax.linear_solve` with respect to vertex positions).

        SciPy equivalent: `scipy.sparse.linalg.aslinearoperator(A.to_scipy())`.
        """
        import lineax as lx

        own_symmetric = self.symmetric or (self.hermitian and not _is_complex(self.values))
        flags = {
            "symmetric": own_symmetric if symmetric is None else symmetric,
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

    Flagged symmetric. SciPy: `scipy.sparse.diags(values)`.

    Args:
        values: `(n,)` the diagonal.
        positive_semidefinite: the caller's promise that `values >= 0`, flagged on the result (keyword-only;
            default `False`).

    Returns:
        `(n, n)` diagonal `SparseMatrix` in `values`' dtype.
    """
    values = device_array(values)
    if values.ndim != 1:
        raise DDGInputError(f"values: expected shape (n,), got {values.shape}")
    return SparseMatrix(
        values, SparsityPattern.diagonal(values.shape[0]), symmetric=True, positive_semidefinite=positive_semidefinite
    )


def identity(n: int, *, dtype=None) -> SparseMatrix:
    """The `(n, n)` identity as a diagonal `SparseMatrix`, flagged symmetric positive semidefinite.

    So `A + s * identity(n)` is `A + s I` on `A`'s pattern (the diagonal is added onto it) and keeps
    `A`'s PSD flag for a concrete `s >= 0` or `nonnegative(s)`; `A.shifted(s)` is the same without
    building the diagonal. SciPy: `scipy.sparse.identity(n)`.

    Args:
        n: the size, `>= 1`.
        dtype: the element type (keyword-only); `None` (default): JAX's default float.

    Returns:
        `(n, n)` diagonal `SparseMatrix` of ones.
    """
    n = check_count("n", n, minimum=1)
    return diagonal_matrix(jnp.ones(n, dtype), positive_semidefinite=True)


def from_scipy(matrix: sp.spmatrix, *, positive_semidefinite: bool = False) -> SparseMatrix:
    """`SparseMatrix` (host-built ELL pattern) with the entries of a SciPy sparse matrix (duplicates summed).

    `symmetric` is set when the matrix equals its transpose exactly, and for a complex matrix
    `hermitian` when it equals its conjugate transpose exactly (checked on the host; a real matrix is
    not flagged `hermitian`, its `symmetric` flag says it).

    Args:
        matrix: a SciPy sparse matrix or array, any format (read on the host).
        positive_semidefinite: the caller's promise that the matrix is positive semidefinite, flagged on the
            result (keyword-only; default `False`); it needs a symmetric real matrix or a Hermitian complex one.

    Returns:
        `SparseMatrix` of `matrix`'s shape, its values in JAX's canonical dtype of `matrix`'s.
    """
    coo = sp.coo_matrix(matrix)
    pattern, slot = SparsityPattern.from_coo(coo.row, coo.col, coo.shape)
    values = np.zeros(pattern.nnz, dtype=coo.data.dtype)
    np.add.at(values, slot, coo.data)
    csr = coo.tocsr()
    square = csr.shape[0] == csr.shape[1]
    symmetric = square and (csr != csr.T).nnz == 0
    complex_values = np.iscomplexobj(values)
    hermitian = complex_values and square and (csr != csr.conj().T).nnz == 0
    if positive_semidefinite and complex_values and not hermitian:
        raise DDGInputError(
            "positive_semidefinite: the complex matrix is not Hermitian (A != conj(A).T), so it cannot be flagged semidefinite"
        )
    if positive_semidefinite and not symmetric and not complex_values:
        raise DDGInputError("positive_semidefinite: the matrix is not symmetric, so it cannot be flagged semidefinite")
    return SparseMatrix(
        device_array(values),
        pattern,
        symmetric=symmetric,
        positive_semidefinite=positive_semidefinite,
        hermitian=hermitian,
    )


def _broadcast(values: Inexact[Array, " m"], x: Inexact[Array, "n *batch"]) -> Inexact[Array, " m *ones"]:
    return values.reshape(values.shape + (1,) * (x.ndim - 1))


def _is_complex(values) -> bool:
    """Complex dtype (static: dtypes are known under jit too)."""
    return bool(jnp.iscomplexobj(values))


def _flags(matrix: SparseMatrix) -> dict:
    return {
        "symmetric": matrix.symmetric,
        "positive_semidefinite": matrix.positive_semidefinite,
        "negative_semidefinite": matrix.negative_semidefinite,
        "hermitian": matrix.hermitian,
    }


def _real_hermitian(matrix: SparseMatrix) -> bool:
    """Flagged `hermitian` with real values, so symmetric too (whether or not flagged so)."""
    return matrix.hermitian and not _is_complex(matrix.values)


def _is_real_scalar(scalar) -> bool:
    """Is the scalar provably real on the host? A `NonNegative`, or any real dtype (concrete or traced)."""
    if isinstance(scalar, NonNegative):
        return True
    return not np.iscomplexobj(scalar)


def _sign_bounds(scalar) -> tuple[bool, bool]:
    """`(scalar >= 0, scalar <= 0)`, each True only where provable on the host.

    A concrete real number is looked at (NaN proves neither); a `NonNegative` is `>= 0` by its check;
    a traced or complex scalar proves nothing.
    """
    if isinstance(scalar, NonNegative):
        return True, False
    if is_traced(scalar) or np.iscomplexobj(scalar):
        return False, False
    value = float(np.asarray(scalar))
    return value >= 0, value <= 0


def _scaled(matrix: SparseMatrix, values: Inexact[Array, " nnz"], scalar) -> SparseMatrix:
    """`matrix` with new `values = scalar * matrix.values`: semidefinite flags follow the provable sign of `scalar`.

    `symmetric` is kept for any scalar, `hermitian` for a real one (`c A` with complex `c` is not
    Hermitian; a real Hermitian, i.e. symmetric, matrix then becomes complex symmetric).
    """
    psd, nsd = matrix.positive_semidefinite, matrix.negative_semidefinite
    at_least_zero, at_most_zero = _sign_bounds(scalar)
    real = _is_real_scalar(scalar)
    zero = matrix.self_adjoint and at_least_zero and at_most_zero  # 0 * A = 0 is both
    return SparseMatrix(
        values,
        matrix.pattern,
        symmetric=matrix.symmetric or (_real_hermitian(matrix) and not real),
        positive_semidefinite=zero or (psd and at_least_zero) or (nsd and at_most_zero),
        negative_semidefinite=zero or (nsd and at_least_zero) or (psd and at_most_zero),
        hermitian=matrix.hermitian and real,
    )


def _add(a: SparseMatrix, b: SparseMatrix, sign: float) -> SparseMatrix:
    """`a + sign * b` on the larger of the two patterns (equal patterns, or one of them diagonal)."""
    op = "+" if sign > 0 else "-"
    if not isinstance(b, SparseMatrix):
        raise DDGInputError(f"other: SparseMatrix {op} needs another SparseMatrix, got {type(b).__name__}")
    if a.shape != b.shape:
        raise DDGInputError(f"A {op} B needs equal shapes, got {a.shape} and {b.shape}")
    a_values, b_values = a.values, b.values
    if _is_complex(a_values) != _is_complex(b_values):  # real + complex: both complex first (the diagonal adds
        dtype = jnp.result_type(a_values, b_values)  # write into one operand's array, which must hold the sum)
        a_values, b_values = a_values.astype(dtype), b_values.astype(dtype)
    if _same_positions(a.pattern, b.pattern, op):
        values, pattern = _plus(a_values, sign, b_values), a.pattern
    elif b.pattern.is_diagonal:
        values, pattern = _add_to_diagonal(a_values, a.pattern, _times(b_values, sign), f"A {op} D"), a.pattern
    elif a.pattern.is_diagonal:
        values, pattern = _add_to_diagonal(_times(b_values, sign), b.pattern, a_values, f"D {op} A"), b.pattern
    else:
        raise DDGInputError(
            f"A {op} B needs matching sparsity patterns (or one diagonal); got shape/layout/width/nnz "
            f"{_static(a.pattern)} and {_static(b.pattern)} (add matrices assembled on the same pattern, "
            "e.g. cotan_laplacian and mass_matrix)"
        )
    b_psd, b_nsd = b.positive_semidefinite, b.negative_semidefinite
    if sign < 0:  # -B swaps the two semidefinite flags
        b_psd, b_nsd = b_nsd, b_psd
    # Hermitian when both are self-adjoint (a real symmetric matrix is Hermitian): set for a complex
    # sum, and for a real one where an operand was flagged so (real sums of symmetric matrices stay as before).
    hermitian = a.self_adjoint and b.self_adjoint and (_is_complex(values) or a.hermitian or b.hermitian)
    return SparseMatrix(
        values,
        pattern,
        symmetric=a.symmetric and b.symmetric,
        positive_semidefinite=a.positive_semidefinite and b_psd,
        negative_semidefinite=a.negative_semidefinite and b_nsd,
        hermitian=hermitian,
    )


def _add_to_diagonal(values, pattern: SparsityPattern, diagonal, what: str):
    """`values` of a square matrix on `pattern` plus `diagonal` (`(n,)`, or a scalar) on its main diagonal (no search, no scatter).

    `what` names the operation in error messages (`"A + D"`, `"A.shifted(s)"`).
    """
    n = pattern.shape[0]
    diagonal = device_array(diagonal)
    if pattern.diagonal_first:
        return _plus_on_diagonal(values, diagonal, n=n)  # slots 0..n-1 are the diagonal
    if pattern.layout == "csr":  # distinct entries: exactly one slot per diagonal position
        on_diagonal = pattern.rows == pattern.cols
        if not (is_traced(pattern.rows) or is_traced(pattern.cols)):
            missing = np.setdiff1d(np.arange(n), np.asarray(pattern.rows)[np.asarray(on_diagonal)])
            if missing.size:
                raise DDGInputError(
                    f"{what}: the pattern lacks diagonal entries (first at row {int(missing[0])}), so a diagonal "
                    "cannot be added onto it"
                )
        else:  # a pattern passed into jit: counted when the program runs
            result = RESULTS.where(jnp.sum(on_diagonal) == n, RESULTS.successful, RESULTS.missing_diagonal)
            values = raise_if_failed(values, result, throw=True)
        return values + jnp.where(on_diagonal, jnp.broadcast_to(diagonal, (n,))[pattern.rows], 0)
    raise DDGInputError(
        f"{what}: adding a diagonal needs a pattern that stores the whole diagonal (a host-built "
        f"square pattern with every diagonal entry, or a CSR pattern); got layout {pattern.layout!r} with "
        f"diagonal_first={pattern.diagonal_first}"
    )


# Eager products run as one compiled program per pattern layout and shape (`SparseMatrix.__matmul__`).
_compiled_product = kernel(SparseMatrix._product)


# The arithmetic on values runs as kernels too: an eager `jnp` operation would compile a program per
# size that JAX keeps, where a kernel's programs are bounded (`ddgjax._compile`).
@kernel
def _times(values: Inexact[Array, " nnz"], scalar) -> Inexact[Array, " nnz"]:
    return values * scalar


@kernel
def _plus(a: Inexact[Array, " nnz"], sign, b: Inexact[Array, " nnz"]) -> Inexact[Array, " nnz"]:
    return a + sign * b


@kernel(static_argnames=("n",))
def _plus_on_diagonal(values: Inexact[Array, " nnz"], diagonal: Inexact[Array, "*n"], *, n: int) -> Inexact[Array, " nnz"]:
    """`values` of a diagonal-first pattern with `diagonal` (`(n,)` or a scalar) added to its first `n` slots."""
    return values.at[:n].add(diagonal)


def _stored(x: Inexact[Array, "n *batch"]) -> Inexact[Array, "n *batch"]:
    """`x`, stored in memory before the product gathers from it.

    XLA:CPU fuses the elementwise producer of a gather's operand into the gather and recomputes it
    for every gathered element; when that producer is itself a sparse product, the work multiplies
    by the row width (`A @ (A @ x)` took 3-5x the time of two products on a 41k-row Laplacian). A
    scatter is never fused into its consumer, so adding zero to one element makes XLA store `x`
    first, for the cost of that element's write.
    """
    return x.at[(0,) * x.ndim].add(jnp.zeros((), x.dtype)) if x.size else x


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


def _is_jax_sparse(x) -> bool:
    """Whether `x` is a `jax.experimental.sparse` array (never, unless the caller has imported that module)."""
    jsparse = sys.modules.get("jax.experimental.sparse")
    return jsparse is not None and isinstance(x, jsparse.JAXSparse)


def incidence_matrix(cols: Int[Array, "n k"], values: Float[Array, "n k"], n_cols: int) -> SparseMatrix:
    """The `(n, n_cols)` matrix whose row `i` holds `values[i]` at the `k` distinct columns `cols[i]`, in any order.

    The signed incidence matrices of DEC (`ddgjax.dec.d0`, `d1`; `ddgjax.volume.d0`, `d1`, `d2`). Each row's
    columns are put in increasing order by their rank among the row's `k` (a comparison, not a sort:
    cheap to trace and compile on millions of rows), so the pattern is CSR with `k` entries per row,
    built from the arrays alone inside jit. Shared through `ddgjax.sparse.internal`.
    """
    n_rows, per_row = cols.shape
    rank = jnp.sum(cols[:, None, :] < cols[:, :, None], axis=-1)
    which = rank[:, None, :] == jnp.arange(per_row)[None, :, None]
    cols = jnp.sum(jnp.where(which, cols[:, None, :], 0), axis=-1).astype(cols.dtype)
    values = jnp.sum(jnp.where(which, values[:, None, :], 0), axis=-1)
    pattern = SparsityPattern(
        rows=jnp.repeat(jnp.arange(n_rows, dtype=cols.dtype), per_row),
        cols=cols.reshape(-1),
        indptr=jnp.arange(0, n_rows * per_row + 1, per_row, dtype=cols.dtype),
        shape=(n_rows, n_cols),
    )
    return SparseMatrix(values=values.reshape(-1), pattern=pattern)
