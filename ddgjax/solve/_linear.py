"""Differentiable solves of symmetric positive definite sparse systems `A x = b`.

`linear_solve(A, b)` solves with one of two backends, chosen by `method=`:

- `"cholesky"`: a sparse direct Cholesky factorisation on the host, CHOLMOD called through XLA's
  foreign-function interface by `sparsax` (so it runs inside `jit`, `lax.scan` and `vmap`, with no
  Python round trip); the symbolic analysis of a pattern is computed once and cached. Installed by
  the `cholmod` extra (`pip install "ddgjax[cholmod]"`): its wheels bundle GPL-2+ CHOLMOD modules,
  so the MIT bare install leaves it out (benchmarks/README.md compares the candidates).
- `"cg"`: a Jacobi-preconditioned conjugate gradient in pure JAX (`preconditioned_cg`), for any
  device and jit-only pipelines.

Both are differentiable with respect to `b` and to the matrix values by implicit differentiation
(`jax.lax.custom_linear_solve`): with `x = A^{-1} b`, the tangent is `dx = A^{-1} (db - dA x)` and,
`A` being symmetric, the cotangent `g` of `x` gives the adjoint `lambda = A^{-1} g` and

    b_bar = lambda,    A_bar[i, j] = -lambda_i x_j   (on the stored positions only),

each one more solve with the same backend (the same CHOLMOD factor). Forward and reverse mode to
any order (`jax.jvp`, `jax.grad`, Hessian-vector products), `vmap`, `jit` and `lax.scan`. Gradients
with respect to vertex positions follow by the chain rule through the assembly of `A`'s values
(`cotan_laplacian`, `mass_matrix`).

Failures that depend on the values follow the results convention (`ddgjax.RESULTS`): a CG that
did not reach its tolerance in `max_steps` (`max_steps_reached`), a solution whose relative
residual `|A x - b| / |b|` exceeds `residual_tolerance` (`singular`: the matrix is singular or too
ill-conditioned for the backend), or non-finite values (`nonfinite`). With `throw=True` (default)
they raise through `equinox.error_if`; with `throw=False` the caller inspects `result`. A matrix
that is not positive definite fails CHOLMOD's factorisation, which raises from the XLA runtime
whatever `throw` is (CHOLMOD reports the failing column).

References: M. B. Giles, "Collected matrix derivative results for forward and reverse mode
algorithmic differentiation" (2008), for `A_bar = -lambda x^T`; lineax (P. Kidger et al.) for the
results convention; Y. Chen, T. A. Davis et al., "CHOLMOD" (2008).
SciPy: `scipy.sparse.linalg.spsolve` / `cg`; libigl: `min_quad_with_fixed` for the Dirichlet blocks.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_choice
from .._results import RESULTS, raise_if_failed
from ..sparse import SparseMatrix

METHODS = ("auto", "cholesky", "cg")


class LinearSolution(eqx.Module):
    """The answer of `linear_solve`: the solution, the outcome and what the solver did.

    Attributes:
        value: `x`, the shape of `b` (`(n,)` or `(n, k)`).
        result: an item of `ddgjax.RESULTS` (`RESULTS.successful` when `x` solves the system).
        residual: `|A x - b| / |b|` (Frobenius norms for a block `b`; 0 for `b = 0`).
        num_steps: CG iterations (the largest over the columns of a block); 0 for `"cholesky"`.
        method: the backend that ran (static).
    """

    value: Float[Array, "n *k"]
    result: RESULTS
    residual: Float[Array, ""]
    num_steps: Int[Array, ""]
    method: str = eqx.field(static=True)


def linear_solve(
    A: SparseMatrix,
    b: Float[ArrayLike, "n *k"],
    *,
    method: str = "auto",
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
    throw: bool = True,
) -> LinearSolution:
    """Solve `A x = b` for a symmetric positive definite `SparseMatrix` `A`, differentiably.

    Args:
        A: `(n, n)` `SparseMatrix` flagged symmetric (e.g. `cotan_laplacian`, `mass_matrix`,
            `M + t * L`, a free-free Dirichlet block); positive definite by the caller's promise.
        b: `(n,)` or `(n, k)` right-hand side(s).
        method: `"cholesky"` (host CHOLMOD through `sparsax`), `"cg"` (pure-JAX Jacobi-preconditioned
            conjugate gradient) or `"auto"` (`"cholesky"` on a CPU backend where `sparsax` is
            installed, `"cg"` elsewhere).
        rtol: relative tolerance of the CG (`|r| <= rtol |b|`); the direct solve ignores it.
        max_steps: CG iteration limit (default `10 n`).
        residual_tolerance: a solution with a larger relative residual is reported as `singular`.
        throw: raise on failure (default) or return the `LinearSolution` to inspect.

    Returns:
        `LinearSolution` with `value` the shape of `b`.

    Differentiable in `b` and `A.values` (module docstring), under `jit`, `grad`, `vmap` and inside
    `lax.scan`. SciPy: `scipy.sparse.linalg.spsolve(A.to_scipy(), b)`.
    """
    method, max_steps, b = _check(A, b, method, max_steps)
    options = (method, float(rtol), max_steps)
    value, stats = _solve_factored(options, A, None, b)
    return _solution(A, b, value, stats, method, residual_tolerance, throw)


def _solution(A, b, value, stats, method, residual_tolerance, throw) -> LinearSolution:
    """The `LinearSolution` of a computed `value`: its residual and outcome (`RESULTS`), raised if `throw`."""
    residual = _relative_residual(A, value, b)
    num_steps, converged = (jnp.asarray(stat) for stat in stats)
    result = RESULTS.where(
        ~jnp.all(jnp.isfinite(value)),
        RESULTS.nonfinite,
        RESULTS.where(
            ~converged,
            RESULTS.max_steps_reached,
            RESULTS.where(residual > residual_tolerance, RESULTS.singular, RESULTS.successful),
        ),
    )
    solution = LinearSolution(value=value, result=result, residual=residual, num_steps=num_steps, method=method)
    return raise_if_failed(solution, result, throw)


class Factorization(eqx.Module):
    """A factorisation of a symmetric positive definite `SparseMatrix`, kept for many right-hand sides.

    Made by `factorize(A, method=...)`; `factorization.solve(b)` solves `A x = b` reusing it, with
    the same differentiation rules as `linear_solve` (tangent and adjoint solves reuse the factor). For
    `"cholesky"` the numeric CHOLMOD factor is held by `sparsax` and referenced by `token`; its cache
    keeps a bounded number of factors per sparsity pattern (`sparsax.set_num_cache_size`), and a
    token whose factor was evicted raises when used, it never answers wrongly. For `"cg"` there is
    nothing to factor: `solve` runs the preconditioned iteration.

    Attributes:
        matrix: the `SparseMatrix` `A`.
        token: CHOLMOD factor reference (`"cholesky"`), else `None`.
        method, rtol, max_steps, residual_tolerance: as given to `factorize` (static).
    """

    matrix: SparseMatrix
    token: Int[Array, "2"] | None
    method: str = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    residual_tolerance: float = eqx.field(static=True)

    def solve(self, b: Float[ArrayLike, "n *k"], *, throw: bool = True) -> LinearSolution:
        """Solve `A x = b` for `b` of shape `(n,)` or `(n, k)`, reusing the factorisation."""
        A = self.matrix
        _, _, b = _check(A, b, self.method, self.max_steps)
        options = (self.method, self.rtol, self.max_steps)
        value, stats = _solve_factored(options, A, self.token, b)
        return _solution(A, b, value, stats, self.method, self.residual_tolerance, throw)


def factorize(
    A: SparseMatrix,
    *,
    method: str = "auto",
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
) -> Factorization:
    """Factor a symmetric positive definite `SparseMatrix` once, for `Factorization.solve(b)` many times.

    Options as in `linear_solve`. Works inside `jit` (the factor is made when the program runs) and
    differentiably (through `Factorization.solve`). A matrix that is not positive definite fails
    CHOLMOD's factorisation, which raises from the XLA runtime.
    SciPy: `scipy.sparse.linalg.splu(A).solve`; cholespy: `CholeskySolverD(...).solve`.
    """
    method, max_steps, _ = _check(A, jnp.zeros(A.shape[0], A.values.dtype), method, max_steps)
    token = None
    if method == "cholesky":
        token = _cholmod_factor(A.pattern, jax.lax.stop_gradient(A.values))
    return Factorization(
        matrix=A,
        token=token,
        method=method,
        rtol=float(rtol),
        max_steps=max_steps,
        residual_tolerance=float(residual_tolerance),
    )


def _check(A, b, method, max_steps):
    if not isinstance(A, SparseMatrix):
        raise DDGInputError(
            f"A: expected a ddgjax SparseMatrix (e.g. cotan_laplacian(mesh) or ddgjax.sparse.from_scipy(matrix)), "
            f"got {type(A).__name__}"
        )
    n_rows, n_cols = A.shape
    if n_rows != n_cols:
        raise DDGInputError(f"A: expected a square matrix, got shape {A.shape}")
    if not A.symmetric:
        raise DDGInputError(
            "A: expected a symmetric matrix (flagged `symmetric`, as the Laplacian and mass matrices are); "
            "linear_solve solves symmetric positive definite systems"
        )
    if np.ndim(b) not in (1, 2) or np.shape(b)[0] != n_rows:
        raise DDGInputError(f"b: expected shape ({n_rows},) or ({n_rows}, k), got {np.shape(b)}")
    check_choice("method", method, METHODS)
    if method == "auto":
        direct = jax.default_backend() == "cpu" and _has_sparsax() and jax.config.jax_enable_x64
        method = "cholesky" if direct else "cg"
    if method == "cholesky" and not jax.config.jax_enable_x64:
        raise DDGInputError(
            "method: 'cholesky' works in float64, which JAX has off; enable it with "
            "jax.config.update('jax_enable_x64', True), or use method='cg'"
        )
    if method == "cholesky" and not _has_sparsax():
        raise DDGInputError(
            "method: 'cholesky' needs the sparsax package (CHOLMOD through XLA FFI), which is not installed; "
            "install it with `pip install \"ddgjax[cholmod]\"` (its wheels bundle GPL-2+ CHOLMOD code), or use method='cg'"
        )
    if max_steps is None:
        max_steps = 10 * n_rows
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise DDGInputError(f"max_steps: expected an integer >= 1, got {max_steps!r}")
    b = jnp.asarray(b)
    if not jnp.issubdtype(b.dtype, jnp.floating):
        b = b.astype(A.values.dtype)
    return method, int(max_steps), b


def _cholmod_factor(pattern, values) -> Int[Array, "2"]:
    """A CHOLMOD factor token (`sparsax.factor`) of the matrix with `values` on `pattern`, in float64."""
    import sparsax

    # CHOLMOD reads the upper triangle of the COO list (rows <= cols) and sums repeated positions,
    # so the storage slots go in as they are (ELL padding adds zeros).
    return sparsax.factor(pattern.rows, pattern.cols, values.astype(jnp.float64), pattern.shape[0])


@functools.cache
def _has_sparsax() -> bool:
    try:
        import sparsax  # noqa: F401
    except ImportError:
        return False
    return True


def _relative_residual(A: SparseMatrix, x, b) -> Float[Array, ""]:
    b_norm = jnp.linalg.norm(b)
    return jnp.where(b_norm > 0, jnp.linalg.norm(A @ x - b) / jnp.where(b_norm > 0, b_norm, 1.0), 0.0)


def _solve_factored(options, A: SparseMatrix, token, b):
    """`(x, (num_steps, converged))` with `x = A^{-1} b`, differentiable through `lax.custom_linear_solve` (module docstring).

    JAX differentiates `custom_linear_solve` implicitly: the derivative of `x` comes from `A`'s
    product (`dx = A^{-1} (db - dA x)`), and the transposed solve (reverse mode) calls the same
    backend, which is `A` itself as `A` is symmetric: one CHOLMOD factor serves the forward, the
    tangent and the adjoint solves. The backend itself is never differentiated.
    """
    method, rtol, max_steps = options
    values = jax.lax.stop_gradient(A.values)
    if method == "cholesky":
        import sparsax

        if token is None:
            token = _cholmod_factor(A.pattern, values)

        def backend(_, rhs):
            # CHOLMOD works in float64; a float32 system is solved in float64 and rounded back.
            x = sparsax.solve_factor(token, rhs.astype(jnp.float64)).astype(rhs.dtype)
            return x, (jnp.zeros((), jnp.int32), jnp.ones((), bool))

    else:
        fixed = SparseMatrix(values, A.pattern, symmetric=True)

        def backend(_, rhs):
            return _jacobi_cg(fixed, rhs, rtol, max_steps)

    return jax.lax.custom_linear_solve(A._product, b, backend, symmetric=True, has_aux=True)


def _jacobi_cg(A: SparseMatrix, b, rtol: float, max_steps: int):
    """Conjugate gradient on `A @ x`, preconditioned by `diag(A)^{-1}`; a block `b` column by column."""
    diagonal = A.diagonal()
    inverse = jnp.where(diagonal > 0, 1.0 / jnp.where(diagonal > 0, diagonal, 1.0), 1.0)

    def one(column):
        return preconditioned_cg(A._product, column, lambda r: inverse * r, rtol, max_steps)

    if b.ndim == 1:
        return one(b)
    values, (steps, converged) = jax.vmap(one, in_axes=1, out_axes=(1, 0))(b)
    return values, (jnp.max(steps), jnp.all(converged))


def preconditioned_cg(matvec, b, preconditioner, rtol: float, max_steps: int):
    """`(x, (num_steps, converged))`: preconditioned conjugate gradient for `A x = b`, `A` and the preconditioner SPD.

    Stops when `|b - A x|_2 <= rtol |b|_2` (a norm-wise test: entries of `b` that are exactly zero
    need no special care; `converged`) or after `max_steps` iterations. Pure JAX
    (`lax.while_loop`), any device; `x0 = 0`. Reference: Y. Saad, "Iterative Methods for Sparse
    Linear Systems" (2003), Algorithm 9.1. SciPy: `scipy.sparse.linalg.cg(A, b, M=..., rtol=...)`.
    """
    threshold = (rtol * jnp.linalg.norm(b)) ** 2

    def unfinished(state):
        _, r, _, _, step = state
        return (step < max_steps) & (jnp.vdot(r, r) > threshold)

    def iteration(state):
        x, r, p, rz, step = state
        q = matvec(p)
        alpha = rz / jnp.vdot(p, q)
        x, r = x + alpha * p, r - alpha * q
        z = preconditioner(r)
        rz_next = jnp.vdot(r, z)
        return x, r, z + (rz_next / rz) * p, rz_next, step + 1

    z = preconditioner(b)
    start = (jnp.zeros_like(b), b, z, jnp.vdot(b, z), jnp.zeros((), jnp.int32))
    x, r, _, _, step = jax.lax.while_loop(unfinished, iteration, start)
    return x, (step, jnp.vdot(r, r) <= threshold)
