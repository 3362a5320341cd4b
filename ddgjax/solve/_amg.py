"""Algebraic multigrid for symmetric positive definite `SparseMatrix` systems: a V-cycle preconditioner in JAX.

A smoothed-aggregation hierarchy (Vaněk, Mandel & Brezina 1996) is built once per matrix on the host
by pyamg, then converted into a pytree of JAX arrays (`AMGHierarchy`), so the V-cycle that uses it
(`amg_v_cycle`) is pure JAX: it runs under `jit`, `vmap` and `lax.scan`, on any device. Level `l`
holds the Galerkin operator `A_{l+1} = P_l^T A_l P_l`, the prolongator `P_l` (`n_l x n_{l+1}`) and
the restriction `R_l = P_l^T`; the coarsest level is solved with a dense (pseudo-)inverse.
`amg_refresh` puts new values of the same pattern into a hierarchy inside `jit` (same aggregates
and prolongators, new Galerkin operators, smoothers and coarse inverse), for flows whose matrix
changes every step.

The V-cycle is a *symmetric positive definite* operator `B ~ A^{-1}`, as the conjugate gradient
needs of a preconditioner. Both follow from the smoother: `s` steps of Richardson iteration on
`D^{-1} A` (`D = diag(A)`), `x <- x + w_k D^{-1} (r - A x)`, with the same weights before and after
the coarse correction. Every step's error propagator `I - w_k D^{-1} A` is self-adjoint in the
`A` inner product, and all of them commute (they are polynomials in `D^{-1} A`), so the
post-smoother is the adjoint of the pre-smoother and `B` is symmetric. With `E_S = prod_k (I - w_k
D^{-1} A)` the V-cycle's error propagator is `I - B A = E_S (I - P B_c P^T A) E_S`, and `B` is
positive definite when the smoother contracts in the energy norm, `|1 - w_k lambda| < 1` on the
spectrum of `D^{-1} A` (Stüben 2001, section 2; the coarse `B_c` is the next level's V-cycle, SPD by
induction, and the coarsest is an inverse). The spectral radius of `D^{-1} A` is estimated on each
level by the largest Ritz value of 24 Lanczos steps (a lower bound, accurate to well under 1 % on
Laplacians), raised by 5 % to `rho`, and the weights are

- `"chebyshev"` (default): `w_k = 1 / tau_k`, `tau_k` the roots of the degree-`s` Chebyshev
  polynomial on `[rho / 30, 1.1 rho]`, so the smoother's residual polynomial is that Chebyshev
  polynomial scaled to 1 at 0, below 1 in magnitude on `(0, 1.13 rho)` (Adams, Brezina, Hu &
  Tuminaro 2003; pyamg's `chebyshev` smoother uses the same interval). For `s = 1` it is damped
  Jacobi with `w = 1.76 / rho`.
- `"jacobi"`: `w_k = 4 / (3 rho)` (damped Jacobi; `|1 - w lambda| <= 1/3` at `lambda = rho`,
  contracting below `1.5 rho`).

So `B` is SPD as long as the Ritz value is above 84 % (Chebyshev) or 64 % (Jacobi) of the true
largest eigenvalue, a wide safety margin.

Both are point smoothers made of sparse products only: no triangular solve, so they are as parallel
on a GPU as the product itself, unlike Gauss-Seidel (pyamg's default on the host).

References: P. Vaněk, J. Mandel & M. Brezina, "Algebraic multigrid by smoothed aggregation for second
and fourth order elliptic problems", Computing 56 (1996); K. Stüben, "A review of algebraic multigrid",
J. Comput. Appl. Math. 128 (2001); M. Adams, M. Brezina, J. Hu & R. Tuminaro, "Parallel multigrid
smoothing: polynomial versus Gauss-Seidel", J. Comput. Phys. 188 (2003); L. Olson, J. Schroder & R.
Tuminaro, "A new perspective on strength measures in algebraic multigrid", Numer. Linear Algebra
Appl. 17 (2010) (evolution strength); N. Bell, L. Olson & J. Schroder, "PyAMG: algebraic multigrid
solvers in Python", JOSS 7 (2022).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, ArrayLike, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice, is_traced
from ..sparse import SparseMatrix, SparsityPattern, from_scipy

SMOOTHERS = ("chebyshev", "jacobi")

# SciPy's sparse matrices and arrays (pyamg returns arrays).
_HostSparse = sp.spmatrix | sp.sparray

# Chebyshev interval [rho / _CHEBYSHEV_LOWER, _CHEBYSHEV_UPPER * rho] (pyamg's defaults); the factor
# that raises the Lanczos estimate of rho (a lower bound) to an upper bound in practice; the number
# of Lanczos steps (the largest Ritz value is then within a fraction of a percent on Laplacians); and
# the size up to which a level's spectrum is computed densely instead.
_CHEBYSHEV_LOWER = 30.0
_CHEBYSHEV_UPPER = 1.1
_RHO_MARGIN = 1.05
_LANCZOS_STEPS = 24
_DENSE_SIZE = 64


class AMGLevel(eqx.Module):
    """One level of an `AMGHierarchy` that is not the coarsest.

    Attributes:
        A: `(n_l, n_l)` the level's operator (`A_0` is the matrix itself; `A_{l+1} = R_l A_l P_l`).
        P: `(n_l, n_{l+1})` prolongator (coarse to fine).
        R: `(n_{l+1}, n_l)` restriction, `P^T` stored as its own matrix for a fast product.
        inverse_diagonal: `(n_l,)` `1 / diag(A_l)`.
        weights: `(s,)` the smoother's step weights `w_k` (module docstring).
        galerkin: for `amg_refresh` (`refreshable=True`), the `(nnz_{l+1}, nnz_l)` matrix that maps
            the storage values of `A_l` to those of `A_{l+1}` (`G[t, s] = P[i_s, I_t] P[j_s, J_t]`),
            else `None`.
    """

    A: SparseMatrix
    P: SparseMatrix
    R: SparseMatrix
    inverse_diagonal: Float[Array, " n_l"]
    weights: Float[Array, " s"]
    galerkin: SparseMatrix | None = None


class AMGHierarchy(eqx.Module):
    """A smoothed-aggregation multigrid hierarchy as JAX arrays, built by `amg_hierarchy` (a pytree).

    Pass it into `jit` as an argument; `amg_v_cycle(hierarchy, r)` applies one V-cycle,
    `amg_preconditioner(hierarchy)` wraps that as a lineax operator for `lineax.CG`, and
    `amg_refresh(hierarchy, A)` puts new values of the same pattern into it.

    Attributes:
        levels: the `AMGLevel`s, finest first (empty when the matrix is small enough to invert).
        coarse: `(n_c, n_c)` the coarsest operator, as a `SparseMatrix` (its values for `amg_refresh`).
        coarse_inverse: `(n_c, n_c)` the (pseudo-)inverse of the coarsest operator, symmetric.
        smoother: `"chebyshev"` or `"jacobi"` (static).
    """

    levels: tuple[AMGLevel, ...]
    coarse: SparseMatrix
    coarse_inverse: Float[Array, "n_c n_c"]
    smoother: str = eqx.field(static=True)

    @property
    def shape(self) -> tuple[int, int]:
        return self.operators[0].shape

    @property
    def operators(self) -> tuple[SparseMatrix, ...]:
        """The operators `A_0, A_1, ...` of every level, finest first, the coarsest included."""
        return tuple(level.A for level in self.levels) + (self.coarse,)

    @property
    def sizes(self) -> tuple[int, ...]:
        """The number of unknowns on each level, finest first (the coarsest included)."""
        return tuple(A.shape[0] for A in self.operators)

    @property
    def operator_complexity(self) -> float:
        """Stored entries of all levels' operators over those of the finest (pyamg's measure).

        The coarsest level counts as its dense inverse, `n_c^2`, which is what the V-cycle multiplies.
        """
        stored = [A.nnz for A in self.operators[:-1]] + [self.coarse_inverse.size]
        return sum(stored) / stored[0]


def amg_hierarchy(
    A: SparseMatrix,
    /,
    *,
    smoother: str = "chebyshev",
    steps: int = 1,
    strength="auto",
    max_coarse: int = 500,
    max_levels: int = 10,
    refreshable: bool = False,
) -> AMGHierarchy:
    """Build a smoothed-aggregation AMG hierarchy of a symmetric positive (semi)definite matrix, on the host.

    The aggregates, prolongators `P_l` (piecewise-constant tentative prolongators, near-null space
    the constant vector, smoothed by one damped Jacobi step) and Galerkin operators
    `A_{l+1} = P_l^T A_l P_l` come from `pyamg.smoothed_aggregation_solver`; this function converts
    them to `SparseMatrix`es, sets each level's smoother weights (module docstring) and inverts the
    coarsest operator densely (a pseudo-inverse by `eigh`, so a semidefinite matrix such as the
    Laplacian of a closed surface gets a semidefinite preconditioner rather than a failure).

    Built once per matrix, outside `jit`, from concrete values. The result is a pytree of arrays to
    pass into jitted code. It is a symmetric positive definite preconditioner for *any* SPD matrix of
    that size, only a weaker one as the matrix moves away from `A`; `amg_refresh` updates it to new
    values of the same pattern inside `jit`.

    Defaults, measured (benchmarks/README.md): the `"evolution"` strength of connection needs 3-4x fewer
    iterations than pyamg's default `"symmetric"` one on meshes with obtuse triangles (camelhead,
    beetle, armadillo) and as many on M-matrices (graph Laplacians, meshes without obtuse angle sums),
    where `"symmetric"` builds 2-4x faster: `"auto"` picks by the sign of the off-diagonal entries;
    one smoothing step (`steps=1`) is the fastest per solve on CPU.

    Args:
        A: `(n, n)` symmetric positive (semi)definite real `SparseMatrix` (e.g. a free-free Dirichlet
            block of `cotan_laplacian`, `M + t * L`), with concrete values.
        smoother: `"chebyshev"` (default) or `"jacobi"` (module docstring).
        steps: smoothing steps `s >= 1` before and after each coarse correction (the Chebyshev degree).
        strength: pyamg's strength of connection: `"auto"` (default: `"symmetric"` when no off-diagonal
            entry of `A` is positive, else `"evolution"`), or passed through: `"evolution"` (Olson,
            Schroder & Tuminaro 2010), `"symmetric"` (`|a_ij| >= theta sqrt(a_ii a_jj)`, `theta = 0`;
            pyamg's default), `("symmetric", {"theta": 0.08})`, ...
        max_coarse: the coarsest level has at most this many unknowns (inverted densely).
        max_levels: at most this many levels, the coarsest included.
        refreshable: also store, per level, the map from its operator's values to the next one's, so
            `amg_refresh` can rebuild the operators from new values (5-20x the finest matrix's
            storage more: 17x on camelhead with evolution strength).

    Returns:
        `AMGHierarchy` in `A`'s dtype.

    pyamg: `pyamg.smoothed_aggregation_solver(A, symmetry="hermitian", strength=..., max_coarse=...)`.
    """
    if not isinstance(A, SparseMatrix):
        raise DDGInputError(
            f"A: expected a ddgjax SparseMatrix (e.g. cotan_laplacian(mesh), M + t * L, or ddgjax.sparse.from_scipy(matrix)), "
            f"got {type(A).__name__}"
        )
    matrix = _host_matrix(A)
    check_choice("smoother", smoother, SMOOTHERS)
    for name, value in (("steps", steps), ("max_coarse", max_coarse), ("max_levels", max_levels)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise DDGInputError(f"{name}: expected an integer >= 1, got {value!r}")
    ml = pyamg_solver(matrix, strength, int(max_coarse), int(max_levels))
    dtype = A.values.dtype
    operators, prolongators, galerkins = [A], [], []
    for level, coarser in zip(ml.levels[:-1], ml.levels[1:]):
        P = level.P.tocsr()
        diagonal = level.A.diagonal()
        if np.any(diagonal <= 0):
            bad = int(np.flatnonzero(diagonal <= 0)[0])
            raise DDGInputError(
                f"A: a positive definite matrix has a positive diagonal; the level of size {diagonal.size} has "
                f"{diagonal[bad]:.3g} at row {bad}"
            )
        fine = operators[-1]
        if refreshable:
            # The pattern of the product itself (SciPy's product drops entries that cancel exactly,
            # and new values would not cancel), and the map that fills it.
            pattern = from_scipy(_ones(P).T @ _ones(fine.to_scipy()) @ _ones(P)).pattern
            galerkins.append(_galerkin_map(fine.pattern, P, pattern, dtype))
            operators.append(_galerkin_product(galerkins[-1], fine.values, pattern))
        else:
            galerkins.append(None)
            operators.append(_to_jax(coarser.A, dtype, symmetrize=True))
        prolongators.append((_to_jax(P, dtype), _to_jax(P.T, dtype)))
    return _assemble(tuple(operators), tuple(prolongators), tuple(galerkins), smoother=smoother, steps=int(steps))


def amg_refresh(hierarchy: AMGHierarchy, A: SparseMatrix, /) -> AMGHierarchy:
    """The hierarchy of new values `A` on the pattern it was built for, keeping its aggregates and prolongators.

    Recomputes, in JAX, the Galerkin operators `A_{l+1} = P_l^T A_l P_l` (one sparse product with the
    stored map per level), their diagonals and smoother weights (Lanczos), and the coarse
    pseudo-inverse. Works inside `jit` and `lax.scan` (e.g. once per step of an implicit flow),
    needs a hierarchy built with `refreshable=True`. Not differentiated through (a preconditioner
    changes how fast CG converges, not its answer): the values are taken under `stop_gradient`.

    Args:
        hierarchy: an `AMGHierarchy` from `amg_hierarchy(A_0, refreshable=True)`.
        A: `(n, n)` `SparseMatrix` on `A_0`'s pattern (same storage layout), symmetric positive definite.

    Returns:
        `AMGHierarchy` of `A`.
    """
    if not isinstance(A, SparseMatrix):
        raise DDGInputError(f"A: expected a ddgjax SparseMatrix, got {type(A).__name__}")
    if hierarchy.levels and hierarchy.levels[0].galerkin is None:
        raise DDGInputError("hierarchy: amg_refresh needs a hierarchy built with amg_hierarchy(A, refreshable=True)")
    fine = hierarchy.operators[0]
    if A.shape != fine.shape or A.pattern.nnz != fine.pattern.nnz or A.pattern.layout != fine.pattern.layout:
        raise DDGInputError(
            f"A: expected a matrix on the hierarchy's pattern (shape {fine.shape}, {fine.pattern.nnz} slots, layout "
            f"{fine.pattern.layout!r}), got shape {A.shape}, {A.pattern.nnz} slots, layout {A.pattern.layout!r}"
        )
    operators = [eqx.tree_at(lambda m: m.values, fine, jax.lax.stop_gradient(A.values).astype(fine.values.dtype))]
    for level, coarse in zip(hierarchy.levels, hierarchy.operators[1:]):
        operators.append(_galerkin_product(level.galerkin, operators[-1].values, coarse.pattern))
    prolongators = tuple((level.P, level.R) for level in hierarchy.levels)
    galerkins = tuple(level.galerkin for level in hierarchy.levels)
    steps = hierarchy.levels[0].weights.shape[0] if hierarchy.levels else 1
    return _assemble(tuple(operators), prolongators, galerkins, smoother=hierarchy.smoother, steps=steps)


def amg_v_cycle(hierarchy: AMGHierarchy, r: Float[ArrayLike, " n *k"], /) -> Float[Array, " n *k"]:
    """One multigrid V-cycle from a zero initial guess: `B r ~ A^{-1} r`, symmetric positive definite in `r`.

    On level `l`: pre-smooth `x = S_l(0, r)`, restrict the residual `r_c = R_l (r - A_l x)`, recurse
    `x_c = B_{l+1} r_c` (the dense inverse on the coarsest level), prolong `x <- x + P_l x_c`,
    post-smooth `x <- S_l(x, r)`; each smoother `S_l` is `s` steps `x <- x + w_k D_l^{-1} (r - A_l x)`
    with the same weights before and after, which makes `B` symmetric (module docstring). Costs
    `2 s` products with each `A_l` (the first smoothing step from zero needs none) and one with each
    `P_l` and `R_l`. Pure JAX: works under `jit`, `vmap`, `grad` (linear in `r`) and on any device.

    Args:
        hierarchy: `AMGHierarchy` from `amg_hierarchy`.
        r: `(n,)` residual, or an `(n, k)` block (one cycle per column).

    Returns:
        `B r`, the shape of `r`.
    """
    n = hierarchy.shape[0]
    if np.ndim(r) not in (1, 2) or np.shape(r)[0] != n:
        raise DDGInputError(f"r: expected shape ({n},) or ({n}, k), got {np.shape(r)}")
    return _cycle(hierarchy.levels, hierarchy.coarse_inverse, device_array(r))


def amg_preconditioner(hierarchy: AMGHierarchy) -> lx.FunctionLinearOperator:
    """`r -> amg_v_cycle(hierarchy, r)` as a lineax operator tagged symmetric positive semidefinite.

    For `lineax.CG(...)` with `options={"preconditioner": amg_preconditioner(hierarchy)}`.

    Args:
        hierarchy: the `AMGHierarchy` of an `(n, n)` matrix (`amg_hierarchy`).

    Returns:
        A `lineax.FunctionLinearOperator` on `(n,)` vectors of the hierarchy's dtype.
    """
    structure = jax.ShapeDtypeStruct((hierarchy.shape[0],), hierarchy.coarse_inverse.dtype)
    return lx.FunctionLinearOperator(
        lambda r: amg_v_cycle(hierarchy, r), structure, (lx.symmetric_tag, lx.positive_semidefinite_tag)
    )


def _cycle(levels, coarse_inverse, r):
    if not levels:
        return coarse_inverse @ r
    level, coarser = levels[0], levels[1:]
    x = _smooth(level, None, r)
    coarse = _cycle(coarser, coarse_inverse, level.R @ (r - level.A @ x))
    return _smooth(level, x + level.P @ coarse, r)


def _smooth(level: AMGLevel, x, r):
    scale = level.inverse_diagonal.reshape(level.inverse_diagonal.shape + (1,) * (r.ndim - 1))
    return jacobi_steps(level.A.__matmul__, scale, level.weights, x, r)


def jacobi_steps(matvec, inverse_diagonal, weights, x, r):
    """The smoother: `len(weights)` weighted-Jacobi steps `x <- x + w_k D^{-1} (r - A x)`, `matvec(x) = A x`,
    `inverse_diagonal = D^{-1}` (broadcast against `r`); `x = None` stands for zero (no product)."""
    for k in range(weights.shape[0]):
        residual = r if x is None else r - matvec(x)
        step = weights[k] * inverse_diagonal * residual
        x = step if x is None else x + step
    return x


@kernel(static_argnames=("smoother", "steps"))
def _assemble(operators, prolongators, galerkins, *, smoother: str, steps: int) -> AMGHierarchy:
    """The `AMGHierarchy` of the level operators: inverse diagonals, smoother weights, coarse pseudo-inverse.

    One compiled program for every level (per set of level sizes), shared by `amg_hierarchy` and
    `amg_refresh`.
    """
    levels = []
    for A, (P, R), galerkin in zip(operators[:-1], prolongators, galerkins):
        inverse_diagonal = 1.0 / A.diagonal()
        rho = _RHO_MARGIN * _largest_eigenvalue(A, jnp.sqrt(inverse_diagonal))
        if smoother == "jacobi":
            weights = jnp.full(steps, 4.0 / 3.0, A.dtype) / rho
        else:
            lower, upper = 1.0 / _CHEBYSHEV_LOWER, _CHEBYSHEV_UPPER
            angles = np.pi * (2 * np.arange(steps) + 1) / (2 * steps)
            roots = (upper + lower) / 2 + (upper - lower) / 2 * np.cos(angles)  # in units of rho
            weights = device_array(1.0 / roots, A.dtype) / rho
        levels.append(AMGLevel(A=A, P=P, R=R, inverse_diagonal=inverse_diagonal, weights=weights, galerkin=galerkin))
    coarse = operators[-1]
    return AMGHierarchy(levels=tuple(levels), coarse=coarse, coarse_inverse=_pseudo_inverse(coarse), smoother=smoother)


def _largest_eigenvalue(A: SparseMatrix, scale: Float[Array, " n"]) -> Float[Array, ""]:
    """The largest eigenvalue of `S A S` (`S = diag(scale)`), that of `D^{-1} A` for `scale = D^{-1/2}`.

    Dense for small levels; else the largest Ritz value of `_LANCZOS_STEPS` Lanczos steps from a
    fixed start, a lower bound that converges fast for the extreme eigenvalue (Kaniel-Paige); the
    caller adds a margin. Without reorthogonalisation: lost orthogonality only repeats Ritz values.
    """
    n = A.shape[0]
    if n <= _DENSE_SIZE:
        return jnp.linalg.eigvalsh(scale[:, None] * A.todense() * scale[None, :])[-1]
    start = jax.random.normal(jax.random.key(0), (n,), scale.dtype)

    def step(carry, _):
        previous, current, beta = carry
        w = scale * (A @ (scale * current)) - beta * previous
        alpha = current @ w
        w = w - alpha * current
        beta_next = jnp.linalg.norm(w)
        following = w / jnp.where(beta_next > 0, beta_next, 1.0)
        return (current, following, beta_next), (alpha, beta_next)

    zero = jnp.zeros((), scale.dtype)
    initial = (jnp.zeros_like(start), start / jnp.linalg.norm(start), zero)
    _, (alphas, betas) = jax.lax.scan(step, initial, None, length=_LANCZOS_STEPS)
    # The 24 x 24 tridiagonal matrix densely: LAPACK's eigvalsh compiles far faster than JAX's eigh_tridiagonal.
    tridiagonal = jnp.diag(alphas) + jnp.diag(betas[:-1], 1) + jnp.diag(betas[:-1], -1)
    return jnp.linalg.eigvalsh(tridiagonal)[-1]


def _pseudo_inverse(A: SparseMatrix) -> Float[Array, "n n"]:
    """Symmetric pseudo-inverse of a small symmetric positive semidefinite matrix (eigenvalues below n eps max dropped)."""
    dense = A.todense()
    values, vectors = jnp.linalg.eigh((dense + dense.T) / 2)
    keep = values > A.shape[0] * jnp.finfo(values.dtype).eps * jnp.maximum(values[-1], 0.0)
    inverse = (vectors * jnp.where(keep, 1.0 / jnp.where(keep, values, 1.0), 0.0)) @ vectors.T
    return (inverse + inverse.T) / 2


def _galerkin_product(galerkin: SparseMatrix, values, pattern: SparsityPattern) -> SparseMatrix:
    """`P^T A P` on its `pattern` from `A`'s storage `values`: `G @ values`, made exactly symmetric.

    The two sums for `(I, J)` and `(J, I)` run in different orders, so they differ by round-off;
    `(a_IJ + a_JI) / 2` (one gather through the pattern's `transpose_slot`) makes them equal.
    """
    product = galerkin @ values
    product = (product + jnp.take(product, pattern.transpose_slot, mode="fill", fill_value=0)) / 2
    return SparseMatrix(product, pattern, symmetric=True, positive_semidefinite=True)


def _galerkin_map(fine: SparsityPattern, P: _HostSparse, coarse: SparsityPattern, dtype) -> SparseMatrix:
    """The `(coarse.nnz, fine.nnz)` matrix `G` with `values(P^T A P) = G @ values(A)` on the two patterns (host).

    Fine entry `(i, j)` in slot `s` meets every pair of entries `P[i, I]`, `P[j, J]`, and adds
    `P[i, I] P[j, J] a_ij` to coarse position `(I, J)`: `G[slot(I, J), s] += P[i, I] P[j, J]`.
    """
    rows, cols, slots = fine.entries()
    lengths = np.diff(P.indptr)
    n_i, n_j = lengths[rows], lengths[cols]
    count = n_i * n_j
    entry = np.repeat(np.arange(rows.size), count)
    offset = np.arange(entry.size) - np.repeat(np.cumsum(count) - count, count)
    first = P.indptr[rows[entry]] + offset // n_j[entry]
    second = P.indptr[cols[entry]] + offset % n_j[entry]
    target = coarse.slots(P.indices[first], P.indices[second])
    G = sp.csr_matrix((P.data[first] * P.data[second], (target, slots[entry])), shape=(coarse.nnz, fine.nnz))
    return _to_jax(G, dtype)


def _ones(matrix: _HostSparse) -> sp.csr_matrix:
    """The matrix with every stored entry (explicit zeros too) set to 1: products of these cannot cancel."""
    return sp.csr_matrix((np.ones(matrix.nnz), matrix.indices, matrix.indptr), shape=matrix.shape)


def pyamg_solver(matrix: _HostSparse, strength="symmetric", max_coarse: int = 500, max_levels: int = 10):
    """pyamg's smoothed-aggregation solver, in float64 (some of pyamg's kernels exist for no other real
    type), made deterministic.

    `strength`: `"symmetric"` (pyamg's default; the `"pyamg"` backend's, whose hierarchy serves one
    solve or a few), `"evolution"` (Olson, Schroder & Tuminaro 2010), or `"auto"`: `"symmetric"` for an
    M-matrix (no positive off-diagonal entry: every graph Laplacian, the cotan Laplacian of a mesh
    without obtuse angle sums, `M + t L` of those) and `"evolution"` otherwise, `amg_hierarchy`'s
    default: on meshes with obtuse triangles (camelhead, beetle) evolution strength needs 3-4x fewer
    CG iterations, for a set-up 2-4x slower, which pays only over many solves. The prolongator's Jacobi
    smoothing step is weighted locally (`weighting="local"`, a Gershgorin bound per row) rather than by
    an Arnoldi estimate of the spectral radius: the same iteration counts on every mesh measured,
    without the Arnoldi's share of the set-up (benchmarks/README.md, "Laplacian systems at scale").

    pyamg draws Lanczos start vectors from NumPy's global generator (the evolution strength's
    spectral radius); a fixed seed makes the hierarchy the same on every build, and the caller's
    generator state is put back.
    """
    import pyamg

    matrix = sp.csr_matrix(matrix, dtype=np.float64)
    if strength == "auto":
        strength = "symmetric" if is_m_matrix(matrix) else "evolution"
    # pyamg reads the legacy global generator, so that is the one to seed (NPY002).
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(0)  # noqa: NPY002
    try:
        return pyamg.smoothed_aggregation_solver(
            matrix,
            symmetry="hermitian",
            strength=strength,
            smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
            max_coarse=max_coarse,
            max_levels=max_levels,
            keep=False,
        )
    finally:
        np.random.set_state(state)  # noqa: NPY002


def is_m_matrix(matrix: _HostSparse) -> bool:
    """Whether no off-diagonal entry is positive (the sign pattern of an M-matrix; definiteness is not checked)."""
    coo = sp.coo_matrix(matrix)
    return not np.any(coo.data[coo.row != coo.col] > 0)


def _host_matrix(A) -> sp.csr_matrix:
    """The host CSR copy of `A`, refusing what the hierarchy cannot be built from."""
    if isinstance(A, SparseMatrix):
        if is_traced(A.values):
            raise DDGInputError(
                "A: the AMG hierarchy is built on the host from concrete values; call amg_hierarchy outside jit "
                "and pass the hierarchy into the jitted function (amg_refresh updates it inside jit)"
            )
        matrix = A.to_scipy()
    elif sp.issparse(A):
        matrix = sp.csr_matrix(A)
    else:
        raise DDGInputError(f"A: expected a ddgjax SparseMatrix (e.g. cotan_laplacian(mesh), M + t * L), got {type(A).__name__}")
    if matrix.shape[0] != matrix.shape[1]:
        raise DDGInputError(f"A: expected a square matrix, got shape {matrix.shape}")
    if not np.issubdtype(matrix.dtype, np.floating):
        raise DDGInputError(f"A: expected real floating-point values, got dtype {matrix.dtype}")
    if not np.all(np.isfinite(matrix.data)):
        raise DDGInputError("A: expected finite values, got NaN or inf (pyamg builds no hierarchy from them)")
    if matrix.nnz and abs(matrix - matrix.T).max() > 1e-12 * abs(matrix).max():
        raise DDGInputError("A: expected a symmetric matrix (AMG here preconditions symmetric positive definite systems)")
    return matrix


def _to_jax(matrix: _HostSparse, dtype, *, symmetrize: bool = False) -> SparseMatrix:
    matrix = sp.csr_matrix(matrix)
    if symmetrize:  # a Galerkin product is symmetric only to round-off
        matrix = (matrix + matrix.T) / 2
    return from_scipy(sp.csr_matrix(matrix, dtype=dtype), positive_semidefinite=symmetrize)
