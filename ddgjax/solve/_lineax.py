"""`SparseCholesky`: ddgjax's sparse solves as a lineax solver, so lineax and optimistix can call them.

lineax and optimistix hand a solver a linear operator, often matrix-free (optimistix's Newton passes
`jax.linearize` of the function whose root it seeks: for a minimisation, the Hessian of the energy).
When the matrix has a known sparsity pattern (the vertex-vertex pattern of every energy of per-face
terms in vertex values, such as the Dirichlet, screened and p-Dirichlet energies) it is recovered
from a few products with the operator by column colouring (Curtis, Powell and Reid 1974): columns
that share no row are summed into one seed vector, so `A @ seed_c` holds each of their entries
separately. A distance-2 colouring of the pattern's graph (two columns sharing a row get different
colours) needs about as many products as the largest row has entries squared, at most, and in
practice 10-30 for triangle meshes. The recovered `SparseMatrix` is then factorised
(`ddgjax.solve.factorize`) and each solve reuses the factorisation.

lineax differentiates a solve by implicit differentiation itself, calling `compute` with new
right-hand sides and `transpose` for the adjoint; the matrix is symmetric, so the adjoint reuses
the factorisation.

References: A. R. Curtis, M. J. D. Powell, J. K. Reid, "On the estimation of sparse Jacobian
matrices" (1974); A. H. Gebremedhin, F. Manne, A. Pothen, "What color is your Jacobian? Graph
coloring for computing derivatives" (2005). lineax: `AbstractLinearSolver`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, check_choice
from .._options import LINEAR_SOLVERS
from .._results import RESULTS
from ..sparse import SparseMatrix, SparsityPattern
from ._linear import Factorization, factorize

# ddgjax's outcome of a solve -> lineax's (pairs: enumeration items are not hashable). lineax has no
# item for a failed Cholesky factorisation; its own `lx.Cholesky` reports one as `singular` too.
LINEAX_RESULTS = (
    (RESULTS.max_steps_reached, lx.RESULTS.max_steps_reached),
    (RESULTS.singular, lx.RESULTS.singular),
    (RESULTS.not_positive_definite, lx.RESULTS.singular),
    (RESULTS.nonfinite, lx.RESULTS.nonfinite_input),
)


class ColumnColouring(eqx.Module):
    """Seed vectors that recover a symmetric pattern's entries from products (`column_colouring`).

    Attributes:
        seeds: `(n_colours, n)` 0/1 rows: seed `c` is the indicator of the columns of colour `c`.
        lookup: `(nnz,)` for each storage slot `(i, j)` of the pattern, the flat index `c n + i` of
            its entry in the products `seeds @ A` (`c` the colour of `j`); `n_colours n` for padding.
    """

    seeds: Float[Array, "n_colours n"]
    lookup: Int[Array, " nnz"]


def column_colouring(pattern: SparsityPattern) -> ColumnColouring:
    """A greedy distance-2 colouring of a square symmetric pattern's columns (host, NumPy, concrete arrays)."""
    if pattern.shape[0] != pattern.shape[1]:
        raise DDGInputError(f"pattern: expected a square pattern, got shape {pattern.shape}")
    n = pattern.shape[0]
    rows, cols = (np.asarray(a) for a in (pattern.rows, pattern.cols))
    graph = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n, n))
    graph = (graph + graph.T + sp.identity(n, dtype=np.int8, format="csr")).astype(bool)
    square = (graph @ graph).tocsr()  # two columns conflict when they share a row
    colour = np.full(n, -1, dtype=np.int64)
    for j in range(n):
        used = colour[square.indices[square.indptr[j] : square.indptr[j + 1]]]
        taken = np.zeros(used.size + 1, dtype=bool)
        taken[used[(used >= 0) & (used <= used.size)]] = True
        colour[j] = int(np.argmin(taken))
    n_colours = int(colour.max()) + 1
    seeds = np.zeros((n_colours, n))
    seeds[colour, np.arange(n)] = 1.0
    stored = np.zeros(rows.size, dtype=bool)
    stored[pattern.entries()[2]] = True  # real slots; ELL padding repeats a position and reads 0
    lookup = np.where(stored, colour[cols] * n + rows, n_colours * n)
    return ColumnColouring(seeds=device_array(seeds), lookup=device_array(lookup, dtype=jnp.int32))


def matrix_from_products(pattern: SparsityPattern, colouring: ColumnColouring, product) -> SparseMatrix:
    """The symmetric `SparseMatrix` on `pattern` whose products are `product(v) = A @ v` (one per colour)."""
    products = jax.vmap(product)(colouring.seeds.astype(jnp.result_type(float)))  # (n_colours, n): row c is A seed_c
    flat = jnp.concatenate([products.reshape(-1), jnp.zeros(1, products.dtype)])
    return SparseMatrix(flat[colouring.lookup], pattern, symmetric=True)


class SparseCholesky(lx.AbstractLinearSolver):
    """A lineax solver for symmetric positive definite operators with a known sparsity pattern.

    `SparseCholesky(pattern)` recovers the operator's matrix on `pattern` from a few products (module
    docstring), factorises it with `ddgjax.solve.factorize` (CHOLMOD or SuperLU on CPU, or another `solver`), and
    solves. Use it wherever lineax takes a solver:

        optx.root_find(jax.grad(energy), optx.Newton(rtol, atol, linear_solver=SparseCholesky(pattern)), phi0)
        lx.linear_solve(operator, b, SparseCholesky(pattern))

    For energies of per-face terms in vertex values, the pattern is the Laplacian's
    (`ddgjax.laplacian.cotan_laplacian(mesh).pattern`). The operator's input must be a single
    `(n,)` array. Make the solver outside `jit` (the colouring is host work on the pattern) and reuse
    it. Failures come back as lineax results (`singular`, for a matrix CHOLMOD finds not positive
    definite too; `max_steps_reached`, `nonfinite_input`), which lineax and optimistix raise or report
    with their own `throw`.

    Attributes:
        pattern: the square, symmetric `SparsityPattern` of the operator's matrix.
        colouring: its `ColumnColouring` (built on the host once per pattern).
        solver: `factorize`'s backend (static): `"auto"` (CHOLMOD, else SuperLU, on CPU), `"cholesky"`,
            `"superlu"`, `"cg"` (Jacobi-preconditioned: the recovered matrix is traced, so no AMG
            hierarchy can be built from it) or `"pyamg"`.
    """

    pattern: SparsityPattern
    colouring: ColumnColouring
    solver: str = eqx.field(static=True)

    def __init__(self, pattern: SparsityPattern, *, solver: str = "auto"):
        if not isinstance(pattern, SparsityPattern):
            raise DDGInputError(
                f"pattern: expected a ddgjax SparsityPattern (e.g. cotan_laplacian(mesh).pattern), got {type(pattern).__name__}"
            )
        self.pattern = pattern
        self.colouring = column_colouring(pattern)
        self.solver = check_choice("solver", solver, LINEAR_SOLVERS)

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]) -> Factorization:
        n = self.pattern.shape[0]
        structure = operator.in_structure()
        if not isinstance(structure, jax.ShapeDtypeStruct) or structure.shape != (n,):
            raise DDGInputError(
                f"operator: SparseCholesky expects an operator on ({n},) vectors (the pattern's size), got {structure}"
            )
        matrix = matrix_from_products(self.pattern, self.colouring, operator.mv)
        matrix = SparseMatrix(matrix.values, self.pattern, symmetric=True, positive_semidefinite=True)
        return factorize(matrix, solver=self.solver)

    def compute(self, state: Factorization, vector, options: dict[str, Any]):
        solution = state.solve(vector, throw=False)
        result = lx.RESULTS.successful
        for ours, theirs in LINEAX_RESULTS:
            result = lx.RESULTS.where(solution.result == ours, theirs, result)
        return solution.value, result, {"num_steps": solution.num_steps}

    def transpose(self, state: Factorization, options: dict[str, Any]):
        return state, options  # symmetric

    def conj(self, state: Factorization, options: dict[str, Any]):
        return state, options  # real

    def assume_full_rank(self) -> bool:
        return True
