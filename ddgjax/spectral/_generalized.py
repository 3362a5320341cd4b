"""The smallest eigenpairs of a sparse generalised symmetric problem `L phi = lambda M phi`, differentiable.

`smallest_eigenpairs(L, M, k)` returns the `k` smallest eigenvalues `lambda_1 <= ... <= lambda_k` of
a symmetric positive semidefinite `L` and a symmetric positive definite `M` (the cotan Laplacian and
a mass matrix) and eigenvectors `Phi = [phi_1 ... phi_k]` normalised `Phi^T M Phi = I`, each with a
deterministic sign: its entry of largest magnitude is positive (on a symmetric shape two entries can
tie for largest, and the sign then flips under tiny motions: differentiate sign-independent functions
such as `phi_i^2` there). Within a cluster of equal eigenvalues (the sphere's `2l + 1`) the basis is
whatever the solver found. The answer is an
`Eigenpairs(values, vectors)` named tuple (it unpacks as `values, vectors = ...`).

**Outcome** (`throw=`, `ddgjax.RESULTS`): ARPACK's non-convergence (or a singular shift-invert
factor) on the host and a subspace iteration that runs out of steps or loses the rank of its basis
are `RESULTS.eigensolver_failed`; a mass matrix the dense path finds not positive definite is
`RESULTS.not_positive_definite`. Every answer is then checked against the problem (`_verified`):
an `L` flagged positive semidefinite with `lambda_1` below `-sqrt(eps)` times the spectrum's scale
(the larger of `|lambda_k|` and the median of `L_ii / M_ii`) is `RESULTS.not_positive_definite`, a
pair whose residual exceeds `eps^(1/4)` times that scale `RESULTS.eigensolver_failed`:
what rounding makes of a cotan Laplacian with faces of near-zero area, never a right answer
(`ddgjax.mesh.check_mesh` finds those faces; `robust=True` handles them). `throw=True` (default)
raises with the item's message; `throw=False` returns a `ddgjax.Solution` whose `stats["residual"]` is the largest relative
eigen-residual `|L phi_i - lambda_i M phi_i| / (lambda_k |M phi_i|)` of the `k` pairs.

**Forward**, `method="arpack"` (host, the default on CPU): ARPACK's shift-invert Lanczos (`scipy.sparse.linalg.eigsh(L, k, M, sigma)`,
which factors `L - sigma M` once with SuperLU), called through `jax.pure_callback`, so it runs
inside `jit` and `vmap` (sequentially); small problems (`n <= 2 k + 64`) are solved densely.
The shift `sigma` sits just below zero, `-1e-8 trace(L) / trace(M)`, so `L - sigma M` is definite
even for a singular `L` (a closed surface's constants). `method="subspace"` (the default on an
accelerator) is shift-invert subspace iteration in JAX (`_subspace_iteration`), its solves by
`ddgjax.solve.factorize` (pure JAX with `solver="cg"`, preconditioned by an algebraic-multigrid
V-cycle: built from `L - sigma M` when the values are concrete, or passed in as `preconditioner=`
inside `jit`; a hierarchy of `L` itself serves, as any of a nearby matrix does).

**Reverse mode** (`jax.custom_vjp`, with respect to the values of `L` and `M`): with
`dA_i = (dL - lambda_i dM) phi_i`,

    d lambda_i = phi_i^T dA_i,
    d phi_i    = sum_{j <= k, j != i} phi_j (phi_j^T dA_i) / (lambda_i - lambda_j)
                 - 1/2 phi_i (phi_i^T dM phi_i) + r_i,

where `r_i`, the part outside the computed span, solves `P^T (L - lambda_i M) P r_i = -P^T dA_i`
with `P = I - Phi Phi^T M` (M-orthogonal to `Phi`). Every eigenvalue below `lambda_i` is in the
computed block, so that system is positive definite on its range: its adjoint is solved by a
projected conjugate gradient preconditioned with a factorisation of `L - sigma M`
(`ddgjax.solve.factorize`), one iteration per column, all columns at once. Pairs `i != j` with
`|lambda_i - lambda_j| <= 1e-8 lambda_k` (a cluster) are left out of the first sum: their terms
rotate the basis inside the eigenspace, which is undefined; any function that is invariant under
such rotations (sums over a cluster, spectral distances, heat kernels, projections onto a cluster's
span) gets its exact gradient, and no gradient is ever NaN. A cluster cut by the `k`-th eigenvalue
(`lambda_k == lambda_{k+1}`) makes the eigenvectors of that cluster undefined: ask for a `k` that
closes the cluster (the eigenvalues' gradients are correct regardless). An adjoint solve that does not
converge raises `RESULTS.eigensolver_failed`'s message whatever `throw` was: a gradient has no
outcome to carry it.

References: ARPACK (R. Lehoucq, D. Sorensen, C. Yang, 1998); N. van der Aa, H. ter Morsche, R.
Mattheij, "Computation of eigenvalue and eigenvector derivatives for a general complex-valued
eigensystem" (2007); M. B. Giles (2008) for the adjoint form. SciPy:
`scipy.sparse.linalg.eigsh(L, k, M, sigma=..., which="LM")`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jaxtyping import Array, Float

from .._compile import at_top_level, kernel
from .._errors import DDGInputError, check_choice, check_count, is_traced
from .._options import check_solver
from .._results import RESULTS, Solution, first_failure, outcome, raise_if_failed
from ..solve import AMGHierarchy, amg_hierarchy, factorize
from ..solve.internal import PRECONDITIONERS, auto_solver, preconditioned_cg
from ..sparse import SparseMatrix, nonnegative

# Eigenvalues within this fraction of the largest computed one count as one cluster (module docstring).
_CLUSTER_TOLERANCE = 1e-8
EIGENSOLVERS = ("auto", "arpack", "subspace")
"""`method=` of `smallest_eigenpairs` and `eigenpairs`: the eigensolver (module docstring)."""
# The subspace iteration's stopping test (relative to the block's largest Ritz value) and step limit.
_SUBSPACE_TOLERANCE = 1e-10
_SUBSPACE_MAX_STEPS = 500
# Relative residual of the adjoint conjugate gradient, and its iteration limit.
_ADJOINT_RTOL = 1e-10
_ADJOINT_MAX_STEPS = 1000
# The forward's status codes (an integer array, so the host callback can return one), and their outcomes.
_CONVERGED, _FAILED, _NOT_POSITIVE_DEFINITE = 0, 1, 2


class Eigenpairs(NamedTuple):
    """The `k` smallest eigenpairs of `L phi = lambda M phi`; unpacks as `values, vectors = ...`.

    Attributes:
        values: `(k,)` the eigenvalues, ascending.
        vectors: `(n, k)` their eigenvectors, M-orthonormal (`vectors.T @ M @ vectors = I`), each
            with its entry of largest magnitude positive.
    """

    values: Float[Array, " k"]
    vectors: Float[Array, "n k"]


def smallest_eigenpairs(
    L: SparseMatrix,
    M: SparseMatrix,
    /,
    k: int,
    *,
    method: str = "auto",
    solver: str = "auto",
    preconditioner: str | AMGHierarchy | None = None,
    hermitian_real_form: bool = False,
    throw: bool = True,
) -> Eigenpairs | Solution:
    r"""The `k` smallest eigenpairs of `L phi = lambda M phi` (module docstring), differentiable in both matrices' values.

    $$L\phi = \lambda M\phi, \qquad \frac{\partial\lambda_i}{\partial L} = \phi_i \phi_i^\top, \quad \frac{\partial\lambda_i}{\partial M} = -\lambda_i \phi_i \phi_i^\top$$

    Args:
        L: `(n, n)` symmetric positive semidefinite `SparseMatrix`.
        M: `(n, n)` symmetric positive definite `SparseMatrix` (diagonal or not).
        k: number of eigenpairs, `1 <= k < n`.
        method: `"arpack"` (host, module docstring), `"subspace"` (pure JAX: shift-invert subspace
            iteration, `_subspace_iteration`) or `"auto"` (`"arpack"` on CPU, `"subspace"` elsewhere).
        solver: the `ddgjax.solve.factorize` backend of the subspace iteration's solves with
            `L - sigma M` (`"auto"`; `"cg"` keeps everything in JAX on any device).
        preconditioner: the subspace iteration's conjugate-gradient preconditioner: `None` (an AMG
            hierarchy of `L - sigma M` when the values are concrete, Jacobi when traced), `"jacobi"`,
            `"amg"` (concrete values only) or an `AMGHierarchy` (e.g. `amg_hierarchy(L)`, built
            outside `jit`).
        hermitian_real_form: `L` and `M` are the real forms `[[Re A, -Im A], [Im A, Re A]]` and
            `diag(B, B)` of a complex Hermitian problem `A u = lambda B u` of half the size (`B` real),
            whose eigenvalues all come in pairs (`u` and `i u`, i.e. `[x; y]` and `[-y; x]`): the
            host path solves the complex problem (ARPACK's complex mode, `k / 2` eigenpairs, half the
            unknowns and a quarter of the factor) and returns the pairs, so `k` must be even. Results
            and derivatives are those of the real-form problem.
        throw: raise when the eigensolver fails (default), or return a `ddgjax.Solution` holding the
            pairs, `result` (`RESULTS.eigensolver_failed`, `RESULTS.not_positive_definite`) and
            `stats["residual"]` (module docstring).

    Returns:
        `Eigenpairs(values (k,), vectors (n, k))`, ascending, `Phi^T M Phi = I`, in `L`'s dtype
        (in a `ddgjax.Solution` with `throw=False`).

    SciPy: `scipy.sparse.linalg.eigsh(L, k, M, sigma=0)`; libigl (C++ only): `igl::eigs(L, M, k, igl::EIGS_TYPE_SM, U, D)`.
    """
    for name, matrix in (("L", L), ("M", M)):
        if not isinstance(matrix, SparseMatrix):
            raise DDGInputError(f"{name}: expected a ddgjax SparseMatrix, got {type(matrix).__name__}")
        if not matrix.symmetric or jnp.iscomplexobj(matrix.values):
            raise DDGInputError(f"{name}: expected a real symmetric SparseMatrix (flagged symmetric)")
    n = L.shape[0]
    if L.shape != (n, n) or M.shape != (n, n):
        raise DDGInputError(f"L, M: expected two square matrices of one size, got shapes {L.shape} and {M.shape}")
    k = check_count("k", k)
    if k >= n:
        raise DDGInputError(f"k: expected fewer eigenpairs than unknowns ({n}), got {k}")
    check_choice("method", method, EIGENSOLVERS)
    if method == "auto":
        method = "arpack" if jax.default_backend() == "cpu" else "subspace"
    check_solver(solver)
    preconditioner = _subspace_preconditioner(L, M, method, solver, preconditioner)
    hermitian_real_form = bool(hermitian_real_form)
    if hermitian_real_form and (n % 2 or k % 2):
        raise DDGInputError(f"hermitian_real_form: needs an even size and an even k (pairs), got n = {n}, k = {k}")
    # A hierarchy holds arrays (an argument of the program); a preconditioner's name is static.
    hierarchy = preconditioner if isinstance(preconditioner, AMGHierarchy) else None
    named = None if hierarchy is not None else preconditioner
    if method == "arpack" and at_top_level() and not (is_traced(L.values) or is_traced(M.values)):
        # Eagerly, ARPACK runs here on the host, outside every program: a program that holds its
        # callback could not be kept across processes (`ddgjax._program_store`).
        host = (np.asarray(a) for a in (L.pattern.rows, L.pattern.cols, L.values, M.pattern.rows, M.pattern.cols, M.values))
        values, vectors, status = _host_eigenpairs(*host, n=n, k=k, hermitian_real_form=hermitian_real_form)
        pairs, result, residual = _checked(L, M, values, vectors, status)
    else:
        pairs, result, residual = _solve(
            L, M, hierarchy, k=k, method=method, solver=solver, preconditioner=named, hermitian_real_form=hermitian_real_form
        )
    return outcome(pairs, result, throw, {"residual": residual})


# One program per size for an eager call: op by op, the host callback (a new function each call)
# would be compiled again on every call. The outcome is checked outside (`outcome`).
@kernel(static_argnames=("k", "method", "solver", "preconditioner", "hermitian_real_form"))
def _solve(
    L: SparseMatrix,
    M: SparseMatrix,
    hierarchy: AMGHierarchy | None,
    *,
    k: int,
    method: str,
    solver: str,
    preconditioner: str | None,
    hermitian_real_form: bool,
) -> tuple[Eigenpairs, RESULTS, Float[Array, ""]]:
    """`(pairs, result, residual)` of `smallest_eigenpairs`, after its checks."""
    options = (method, solver, preconditioner if hierarchy is None else hierarchy, hermitian_real_form)
    values, vectors, status = _eigenpairs((L.values, M.values), L.pattern, M.pattern, k, options)
    return _checked_pairs(L, M, values, vectors, status)


def _checked_pairs(L: SparseMatrix, M: SparseMatrix, values, vectors, status) -> tuple[Eigenpairs, RESULTS, Float[Array, ""]]:
    """`(pairs, result, residual)`: the solver's status as an outcome, then `_verified`'s."""
    result = RESULTS.where(
        status == _CONVERGED,
        RESULTS.successful,
        RESULTS.where(status == _FAILED, RESULTS.eigensolver_failed, RESULTS.not_positive_definite),
    )
    pairs = Eigenpairs(values, vectors)
    checked, residual = _verified(L, M, jax.lax.stop_gradient(pairs))
    return pairs, first_failure(result, checked), residual


_checked = kernel(_checked_pairs)


def _verified(L: SparseMatrix, M: SparseMatrix, pairs: Eigenpairs) -> tuple[RESULTS, Float[Array, ""]]:
    """The solver's answer checked against the problem, and its relative residual `stats["residual"]`.

    The residual is `max_i |L phi_i - lambda_i M phi_i| / (lambda_k |M phi_i|)`: relative to the
    spectrum's scale (the subspace iteration stops on the same measure over its larger block; NaN for
    the zeros of a failed host solve). The outcome is relative to
    `scale = max(|lambda_k|, median_i L_ii / M_ii)`:

    - `RESULTS.not_positive_definite` where `L` is flagged positive semidefinite and
      `lambda_1 < -sqrt(eps) scale`;
    - else `RESULTS.eigensolver_failed` where some pair has `|L phi - lambda M phi| > eps^(1/4) scale |M phi|`
      (its eigenvalue may then be off by about that much);
    - `RESULTS.successful` otherwise.

    The scale is the requested spectrum, or the typical one: the median ignores the few huge entries
    of nearly degenerate faces, whose rounding makes a cotan Laplacian indefinite and its "eigenpairs"
    noise. Measured on an icosphere with one face of relative area `r = A / l_max^2`: for
    `r <= 1e-12` (which `ddgjax.mesh.check_mesh` calls zero-area) every method and `k` either
    returns `lambda_1 < -1e-7 scale` or residuals of 3e-3 to 40 times the scale (the subspace
    iteration "converges", by its own test relative to the huge eigenvalues of its block, to a
    positive but wrong `lambda_1 = 0.85 scale`); for `r >= 1e-10` the residuals stay below 3e-6 and
    `lambda_1` above -3e-10 times the scale. Healthy meshes (beetle, camelhead, nefertiti, teddy; plain
    and intrinsic Delaunay; both methods): residuals below 2e-12, `lambda_1` above -4e-18 times it.
    """
    values, vectors = pairs
    mass = M.diagonal()
    ratios = jnp.where(mass > 0, L.diagonal() / jnp.where(mass > 0, mass, 1), jnp.nan)
    scale = jnp.maximum(jnp.abs(values[-1]), jnp.nanmedian(ratios))
    eps = jnp.finfo(values.dtype).eps
    masses = M @ vectors
    residuals = jnp.linalg.norm(L @ vectors - masses * values, axis=0)
    mass_norms = jnp.linalg.norm(masses, axis=0)
    inaccurate = jnp.any(residuals > eps**0.25 * scale * mass_norms)
    result = RESULTS.where(inaccurate, RESULTS.eigensolver_failed, RESULTS.successful)
    if L.positive_semidefinite:  # the more telling outcome first: it names degenerate elements
        negative = values[0] < -jnp.sqrt(eps) * scale
        result = first_failure(RESULTS.where(negative, RESULTS.not_positive_definite, RESULTS.successful), result)
    relative = jnp.max(residuals / mass_norms) / jnp.maximum(jnp.abs(values[-1]), jnp.finfo(values.dtype).tiny)
    return result, relative


def _subspace_preconditioner(L, M, method, solver, preconditioner) -> str | AMGHierarchy | None:
    """The preconditioner the subspace iteration's CG runs with (`None` where it runs no CG), made
    before the custom VJP traces the values: an AMG hierarchy needs them concrete."""
    if preconditioner is not None and not isinstance(preconditioner, AMGHierarchy):
        check_choice("preconditioner", preconditioner, PRECONDITIONERS)
    if method != "subspace" or (solver == "auto" and auto_solver(L.shape[0], preconditioner is not None) != "cg"):
        if preconditioner is not None:
            raise DDGInputError(
                "preconditioner: only the subspace iteration's conjugate gradient takes one (method='subspace', solver='cg')"
            )
        return None
    if solver != "cg":
        if preconditioner is not None:
            raise DDGInputError(f"preconditioner: only solver='cg' takes one; solver={solver!r} does not")
        return None
    traced = is_traced(L.values) or is_traced(M.values)
    if preconditioner is None:
        preconditioner = "jacobi" if traced else "amg"
    if preconditioner == "amg":
        if traced:
            raise DDGInputError(
                "preconditioner: 'amg' builds its hierarchy from concrete matrix values, and these are traced; pass "
                "ddgjax.solve.amg_hierarchy(L) built outside jit, or use 'jacobi'"
            )
        preconditioner = amg_hierarchy(_shifted(L, M))
    return preconditioner


def _host_eigenpairs(l_rows, l_cols, l_values, m_rows, m_cols, m_values, n: int, k: int, hermitian_real_form: bool):
    """NumPy: ARPACK shift-invert (or a dense solve when small), ascending, M-normalised, signs fixed; and
    the status (`_CONVERGED`, or zeros with `_FAILED` / `_NOT_POSITIVE_DEFINITE`)."""
    dtype = l_values.dtype
    try:
        if hermitian_real_form:
            values, vectors = _complex_eigenpairs((l_rows, l_cols, l_values), (m_rows, m_cols, m_values), n, k // 2)
            values = np.repeat(values, 2)
            x, y = vectors.real, vectors.imag
            vectors = np.stack([np.vstack([x, y]), np.vstack([-y, x])], axis=2).reshape(n, k)  # u, i u per pair
        else:
            L = sp.csc_matrix((np.asarray(l_values, np.float64), (l_rows, l_cols)), shape=(n, n))
            M = sp.csc_matrix((np.asarray(m_values, np.float64), (m_rows, m_cols)), shape=(n, n))
            values, vectors = _real_eigenpairs(L, M, k)
    except _EigensolverFailure as failure:
        return np.zeros(k, dtype), np.zeros((n, k), dtype), np.int32(failure.status)
    largest = np.argmax(np.abs(vectors), axis=0)
    vectors = vectors * np.sign(vectors[largest, np.arange(k)])
    return values.astype(dtype), vectors.astype(dtype), np.int32(_CONVERGED)


class _EigensolverFailure(Exception):
    """A host eigensolve that failed, with its status code (`_FAILED` or `_NOT_POSITIVE_DEFINITE`)."""

    def __init__(self, status: int):
        super().__init__(status)
        self.status = status


def _dense_eigenpairs(A: np.ndarray, B: np.ndarray, k: int):
    """The `k` smallest eigenpairs of a small dense problem; SciPy refuses a `B` that is not positive definite."""
    try:
        return sla.eigh(A, B, subset_by_index=(0, k - 1))
    except np.linalg.LinAlgError as error:
        raise _EigensolverFailure(_NOT_POSITIVE_DEFINITE) from error


def _arpack_eigenpairs(A, B, k: int, start: np.ndarray):
    """ARPACK's shift-invert Lanczos below 0, Rayleigh-Ritz on its vectors (`_rayleigh_ritz`)."""
    shift = -1e-8 * A.diagonal().real.sum() / B.diagonal().sum()
    try:
        _, vectors = spla.eigsh(A, k=k, M=B, sigma=shift, which="LM", v0=start, tol=0.0)
        return _rayleigh_ritz(A, B, vectors)
    # No convergence; SuperLU's exactly singular factor (RuntimeError); the block's B-Gram matrix not
    # positive definite (LinAlgError: ARPACK's vectors lost rank).
    except (spla.ArpackNoConvergence, spla.ArpackError, RuntimeError, np.linalg.LinAlgError) as error:
        raise _EigensolverFailure(_FAILED) from error


def _real_eigenpairs(L: sp.csc_matrix, M: sp.csc_matrix, k: int):
    n = L.shape[0]
    if n <= 2 * k + 64:
        return _dense_eigenpairs(L.toarray(), M.toarray(), k)
    start = np.ones(n) + np.linspace(0.0, 1.0, n)  # deterministic; not orthogonal to anything natural
    return _arpack_eigenpairs(L, M, k, start)


def _rayleigh_ritz(A, B, vectors):
    """ARPACK's eigenvectors made exactly B-orthonormal, ascending: inside a cluster of equal eigenvalues
    they need not be orthogonal (complex mode: measured overlaps of 0.7), so the block is
    B-orthonormalised (Cholesky QR) and rotated to the Ritz vectors of `A` in its span (the same
    eigenpairs, as the span is invariant)."""
    gram = vectors.conj().T @ (B @ vectors)
    vectors = sla.solve_triangular(sla.cholesky((gram + gram.conj().T) / 2, lower=True), vectors.conj().T, lower=True).conj().T
    projected = vectors.conj().T @ (A @ vectors)
    values, rotation = sla.eigh((projected + projected.conj().T) / 2)
    return values, vectors @ rotation


def _complex_eigenpairs(l_entries: tuple, m_entries: tuple, n: int, k: int):
    """The `k` smallest eigenpairs of the complex Hermitian problem whose `n x n` real forms have the COO
    entries `(rows, cols, values)` `l_entries`, `m_entries` (see `smallest_eigenpairs(hermitian_real_form=True)`):
    `A = L[:h, :h] + i L[h:, :h]` and `B = M[:h, :h]`, read off the entries (no real form is built)."""
    h = n // 2
    A, B = (_complex_block(*entries, h) for entries in (l_entries, m_entries))
    if h <= 2 * k + 64:
        values, vectors = _dense_eigenpairs(A.toarray(), B.toarray(), k)
    else:
        values, vectors = _arpack_eigenpairs(A, B, k, (np.ones(h) + np.linspace(0.0, 1.0, h)) * (1 + 0.5j))
    return values.real, vectors


def _complex_block(rows, cols, values, h: int) -> sp.csc_matrix:
    """`X[:h, :h] + i X[h:, :h]` of the `2h x 2h` real matrix `X` with these COO entries (repeats summed), CSC."""
    rows, cols, values = np.asarray(rows), np.asarray(cols), np.asarray(values, np.float64)
    real, imaginary = (cols < h) & (rows < h), (cols < h) & (rows >= h)
    if not np.any(values[imaginary]):  # a real matrix (the mass) stays real: ARPACK's B-products are cheaper
        return sp.csc_matrix((values[real], (rows[real], cols[real])), shape=(h, h))
    entries = np.concatenate([values[real], 1j * values[imaginary]])
    positions = (np.concatenate([rows[real], rows[imaginary] - h]), np.concatenate([cols[real], cols[imaginary]]))
    return sp.csc_matrix((entries, positions), shape=(h, h))


def _host_forward(l_pattern, m_pattern, k, hermitian_real_form, l_values, m_values):
    n = l_pattern.shape[0]
    shapes = (
        jax.ShapeDtypeStruct((k,), l_values.dtype),
        jax.ShapeDtypeStruct((n, k), l_values.dtype),
        jax.ShapeDtypeStruct((), jnp.int32),
    )
    return jax.pure_callback(
        lambda *arrays: _host_eigenpairs(*arrays, n=n, k=k, hermitian_real_form=hermitian_real_form),
        shapes,
        l_pattern.rows,
        l_pattern.cols,
        l_values,
        m_pattern.rows,
        m_pattern.cols,
        m_values,
        vmap_method="sequential",
    )


def _forward(l_pattern, m_pattern, k, options, l_values, m_values):
    method, solver, preconditioner, hermitian_real_form = options
    if method == "arpack":
        return _host_forward(l_pattern, m_pattern, k, hermitian_real_form, l_values, m_values)
    L = SparseMatrix(l_values, l_pattern, symmetric=True, positive_semidefinite=True)
    M = SparseMatrix(m_values, m_pattern, symmetric=True, positive_semidefinite=True)
    return _subspace_iteration(L, M, k, solver, preconditioner)


@eqx.filter_custom_vjp
def _eigenpairs(values, l_pattern, m_pattern, k, options):
    return _forward(l_pattern, m_pattern, k, options, *values)


@_eigenpairs.def_fwd
def _eigenpairs_fwd(perturbed, values, l_pattern, m_pattern, k, options):
    eigenvalues, eigenvectors, status = _forward(l_pattern, m_pattern, k, options, *values)
    return (eigenvalues, eigenvectors, status), (eigenvalues, eigenvectors)


@_eigenpairs.def_bwd
def _eigenpairs_bwd(residuals, cotangents, perturbed, values, l_pattern, m_pattern, k, options):
    """`(L_bar, M_bar)` on the patterns' storage slots (module docstring: reverse mode)."""
    eigenvalues, Phi = residuals
    values_bar, Phi_bar, _ = cotangents  # the status is an integer: no cotangent
    l_values, m_values = values
    if values_bar is None:
        values_bar = jnp.zeros_like(eigenvalues)
    L = SparseMatrix(l_values, l_pattern, symmetric=True)
    M = SparseMatrix(m_values, m_pattern, symmetric=True)
    # Each term below is a sum of `a^T (dL - lambda dM) b`, i.e. `L_bar += a b^T` and
    # `M_bar -= lambda a b^T` on the stored positions; collected as columns `(a, b, lambda)`.
    lefts, rights, scales = [Phi * values_bar], [Phi], [eigenvalues]
    if Phi_bar is not None:
        gaps = eigenvalues[None, :] - eigenvalues[:, None]  # [j, i] = lambda_i - lambda_j
        separated = jnp.abs(gaps) > _CLUSTER_TOLERANCE * jnp.max(jnp.abs(eigenvalues))
        overlaps = Phi.T @ Phi_bar  # [j, i] = phi_j^T phi_bar_i
        within = jnp.where(separated, overlaps / jnp.where(separated, gaps, 1.0), 0.0)
        lefts.append(Phi @ within)  # column i: sum_j within[j, i] phi_j, paired with phi_i
        rights.append(Phi)
        scales.append(eigenvalues)
        # The adjoint's preconditioning solves: as the forward's on the subspace path (in JAX on any device).
        method, solver, preconditioner, _ = options
        solves = {"solver": "auto"} if method == "arpack" else {"solver": solver, "preconditioner": preconditioner}
        W = _outside_span_adjoint(L, M, eigenvalues, Phi, Phi_bar, solves)
        lefts.append(W)
        rights.append(Phi)
        scales.append(eigenvalues)
        normalisation = -0.5 * jnp.diagonal(overlaps)  # the M-normalisation: -1/2 phi_i^T dM phi_i
    l_bar = sum(_outer_on_pattern(l_pattern, a, b) for a, b in zip(lefts, rights))
    m_bar = -sum(_outer_on_pattern(m_pattern, a * s, b) for a, b, s in zip(lefts, rights, scales))
    if Phi_bar is not None:
        m_bar = m_bar + _outer_on_pattern(m_pattern, Phi * normalisation, Phi)
    return (l_bar.astype(l_values.dtype), m_bar.astype(m_values.dtype))


def _outer_on_pattern(pattern, a: Float[Array, "n k"], b: Float[Array, "n k"]) -> Float[Array, " nnz"]:
    """`sum_c a[:, c] b[:, c]^T` read at each storage slot `(i, j)` of `pattern` (padding slots hold 0 in
    the matrix and get whatever they get: they read a real position and multiply a zero)."""
    return jnp.sum(a[pattern.rows] * b[pattern.cols], axis=-1)


def _shifted(L: SparseMatrix, M: SparseMatrix) -> SparseMatrix:
    """`L - sigma M` with `sigma = -1e-8 trace(L) / trace(M)`: positive definite even for a singular `L`."""
    shift = -1e-8 * jnp.sum(L.diagonal()) / jnp.sum(M.diagonal())
    L = SparseMatrix(L.values, L.pattern, symmetric=True, positive_semidefinite=True)
    return L + nonnegative(-shift) * M


def _subspace_iteration(L: SparseMatrix, M: SparseMatrix, k: int, solver: str, preconditioner):
    """The `k` smallest eigenpairs by shift-invert subspace iteration, in JAX (Saad 2011, section 5.2).

    A block `X` of `m = min(n, 2 k + 8)` M-orthonormal columns is multiplied by `(L - sigma M)^{-1} M`
    (`sigma` as `_shifted`; one factorisation, `m` solves per step), M-orthonormalised again
    (Cholesky-QR, twice) and rotated to the Ritz vectors of `L` in its span (Rayleigh-Ritz). The error
    in eigenpair `i <= k` falls by about `(lambda_i - sigma) / (lambda_{m+1} - sigma)` per step (< 1/2
    for surface Laplacians, whose eigenvalues grow linearly). It stops when every one of the first
    `k` has `|L phi - lambda M phi| <= 1e-10 lambda_m |M phi|`, or after 500 steps (status `_FAILED`,
    as when the basis loses rank and the residual is NaN). Fixed shapes throughout, so it runs under
    `jit`, `vmap` and on any device. Returns `(values, vectors, status)`.
    """
    n = L.shape[0]
    m = min(n, 2 * k + 8)
    factor = factorize(_shifted(L, M), solver=solver, preconditioner=preconditioner)
    start = jax.random.normal(jax.random.key(0), (n, m), L.values.dtype)

    def orthonormal(Y):
        for _ in range(2):  # Cholesky-QR twice: orthonormal to round-off even when Y is ill-conditioned
            gram = Y.T @ (M @ Y)
            gram = (gram + gram.T) / 2 + 1e-14 * jnp.trace(gram) / m * jnp.eye(m, dtype=Y.dtype)
            Y = jax.scipy.linalg.solve_triangular(jnp.linalg.cholesky(gram), Y.T, lower=True).T
        return Y

    def ritz(Y):
        Q = orthonormal(Y)
        H = Q.T @ (L @ Q)
        values, rotation = jnp.linalg.eigh((H + H.T) / 2)
        X = Q @ rotation
        residual = jnp.linalg.norm(L @ X - (M @ X) * values, axis=0) / jnp.linalg.norm(M @ X, axis=0)
        return values, X, jnp.max(residual[:k]) / jnp.maximum(values[-1], jnp.finfo(values.dtype).tiny)

    def unfinished(state):
        _, _, residual, step = state
        return (residual > _SUBSPACE_TOLERANCE) & (step < _SUBSPACE_MAX_STEPS)  # a NaN residual stops too

    def iteration(state):
        X, _, _, step = state
        values, X, residual = ritz(factor.solve(M @ X, throw=False).value)
        return X, values, residual, step + 1

    values, X, residual = ritz(start)
    X, values, residual, _ = jax.lax.while_loop(unfinished, iteration, (X, values, residual, jnp.zeros((), jnp.int32)))
    status = jnp.where(residual <= _SUBSPACE_TOLERANCE, _CONVERGED, _FAILED).astype(jnp.int32)
    values, X = values[:k], X[:, :k]
    largest = jnp.argmax(jnp.abs(X), axis=0)
    X = X * jnp.sign(X[largest, jnp.arange(k)])
    return values, X, status


def _outside_span_adjoint(L, M, eigenvalues, Phi, Phi_bar, solves: dict):
    """`W = [w_1 ... w_k]`, `w_i = -P z_i` with `P^T (L - lambda_i M) P z_i = P^T phi_bar_i` (module docstring).

    Projected conjugate gradient, preconditioned by `P (L - sigma M)^{-1} P^T` with one kept
    factorisation (`sigma` below the spectrum); all columns at once (`vmap`).
    """
    MPhi = M @ Phi
    project = lambda x: x - Phi @ (MPhi.T @ x)  # P x
    project_t = lambda x: x - MPhi @ (Phi.T @ x)  # P^T x
    shifted = factorize(_shifted(L, M), **solves)

    def column(eigenvalue, phi_bar):
        operator = lambda z: project_t(L @ project(z) - eigenvalue * (M @ project(z)))
        preconditioner = lambda r: project(shifted.solve(project_t(r), throw=False).value)
        z, (_, converged) = preconditioned_cg(operator, project_t(phi_bar), preconditioner, _ADJOINT_RTOL, _ADJOINT_MAX_STEPS)
        # A gradient carries no outcome: a failed adjoint raises whatever the forward's `throw` was.
        result = RESULTS.where(converged, RESULTS.successful, RESULTS.eigensolver_failed)
        return -project(raise_if_failed(z, result, throw=True))

    return jax.vmap(column, in_axes=(0, 1), out_axes=1)(eigenvalues, Phi_bar)
