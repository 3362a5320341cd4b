"""Differentiable solves of symmetric (Hermitian) positive definite sparse systems `A x = b`.

`linear_solve(A, b)` solves with one of four backends, chosen by `solver=` (`ddgjax.LINEAR_SOLVERS`;
a problem-level function passes its `solver=` here):

- `"cholesky"`: a sparse direct Cholesky factorisation on the host, CHOLMOD called through XLA's
  foreign-function interface by `sparsax` (so it runs inside `jit`, `lax.scan` and `vmap`, with no
  Python round trip); the symbolic analysis of a pattern is computed once and cached, supernodal or
  simplicial as CHOLMOD chooses, except for kept factorisations (`factorize` outside `jit`, up to
  `SIMPLICIAL_LIMIT` unknowns), analysed simplicial for their faster solves (`cholmod_analysis`). Installed by
  the `cholmod` extra (`pip install "ddgjax[cholmod]"`): its wheels bundle GPL-2+ CHOLMOD modules,
  so the MIT bare install leaves it out (benchmarks/README.md compares the candidates).
- `"superlu"`: SciPy's sparse LU (`scipy.sparse.linalg.splu`, COLAMD column ordering) on the host,
  through `jax.pure_callback`: the direct solver of the bare install (`ddgjax.solve._host`; SuperLU's
  symmetric mode was measured slower on mesh Laplacians).
- `"cg"`: a preconditioned conjugate gradient in pure JAX (`preconditioned_cg`), for any device and
  jit-only pipelines; the preconditioner is Jacobi (`diag(A)^{-1}`) or an algebraic-multigrid
  V-cycle (`preconditioner="amg"` or an `AMGHierarchy`; `ddgjax.solve._amg`), which keeps the
  iteration count nearly independent of the mesh size and of its bad triangles.
- `"pyamg"`: SciPy's CG preconditioned by pyamg's V-cycle on the host, for systems too large to
  factor.

`"auto"` takes `"cholesky"` on a CPU backend where `sparsax` is installed (and float64 is on); on
other CPU setups `"superlu"` up to 50,000 unknowns and `"pyamg"` above (`SUPERLU_LIMIT`, measured);
and `"cg"` on an accelerator, with the AMG preconditioner when the matrix values are concrete (the
hierarchy is built on the host) and Jacobi inside a trace. One solve (`linear_solve`) of more than
500,000 unknowns on a CPU takes `"pyamg"` whatever is installed (`ITERATIVE_LIMIT`), and of more than
20,000 when `A` has more than 10 stored entries per row, as 3-D graphs and volume meshes do
(`VOLUME_ITERATIVE_LIMIT`): a factorisation's fill makes its cost grow like `n^1.4` on surfaces and like
`n^2` in volumes, pyamg's set-up and CG like `n^1.1`; a kept factorisation (`factorize`) stays direct,
its cost spread over its many faster solves.

Every backend is differentiable with respect to `b` and to the matrix values by implicit
differentiation (`jax.lax.custom_linear_solve`): with `x = A^{-1} b`, the tangent is
`dx = A^{-1} (db - dA x)` and, `A` being symmetric, the cotangent `g` of `x` gives the adjoint
`lambda = A^{-1} g` and

    b_bar = lambda,    A_bar[i, j] = -lambda_i x_j   (on the stored positions only),

each one more solve with the same backend (the same factor). Forward and reverse mode to any order
(`jax.jvp`, `jax.grad`, Hessian-vector products), `vmap`, `jit` and `lax.scan`. Gradients with
respect to vertex positions follow by the chain rule through the assembly of `A`'s values
(`cotan_laplacian`, `mass_matrix`).

Complex Hermitian systems (`A.hermitian`, e.g. a connection Laplacian) are solved as the real
symmetric system of twice the size,

    [Re A  -Im A] [Re x]   [Re b]
    [Im A   Re A] [Im x] = [Im b],

positive definite exactly when `A` is, so every backend and its derivatives serve them unchanged.
A complex `b` with a real `A` is solved as two real columns.

Failures that depend on the values follow the results convention (`ddgjax.RESULTS`) on every
backend, and nothing else raises: NaN or inf in `A` or `b` (`nonfinite`; a factorisation never sees
them), a matrix CHOLMOD finds not positive definite (`not_positive_definite`: indefinite, or
singular to working precision; a host check made just before the factorisation, which the
factorisation then reuses from `sparsax`'s cache), a matrix SuperLU finds exactly singular, or a
solution whose relative residual `|A x - b| / |b|` exceeds `residual_tolerance` (`singular`: the
matrix is singular or too ill-conditioned for the backend), a CG that did not reach its tolerance
in `max_steps` (`max_steps_reached`). A failed factorisation's solves are NaN. With `throw=True`
(default) a failure raises through `equinox.error_if` with the item's message, as everywhere in
ddgjax: `equinox.EquinoxRuntimeError` eagerly and under `equinox.filter_jit`, a
`jax.errors.JaxRuntimeError` with the same message under a plain `jax.jit` (both `RuntimeError`s);
with `throw=False` the caller inspects `result`.

Which symmetric systems each backend accepts (measured in tests/test_solve_backends.py):

| system                            | `"cholesky"`            | `"superlu"` | `"cg"`, `"pyamg"`                         |
|-----------------------------------|-------------------------|-------------|-------------------------------------------|
| positive definite                 | solved                  | solved      | solved                                    |
| nonsingular indefinite / negative | `not_positive_definite` | solved      | solved here, not assured                  |
| singular (a closed surface's `L`) | `singular`              | `singular`  | `singular` or `max_steps_reached`         |

Only CHOLMOD checks definiteness; SuperLU factors any nonsingular matrix; CG and pyamg's
preconditioned CG are only proven for positive definite matrices (on an indefinite one they may
converge, as they do on a shifted Laplacian, or stall into `max_steps_reached`). The flag a
`SparseMatrix` carries (`positive_semidefinite`) is a promise for `"auto"`'s choice, not checked.

Precision: a float32 system (JAX's default while `jax_enable_x64` is off) carries round-off of
~1e-7 relative, enough for a well-posed mesh system to miss `residual_tolerance` or to look
indefinite; the first float32 matrix to reach `factorize` (so `linear_solve`) warns once per
process (`PrecisionWarning`), and the failure messages say so. Mixed dtypes are promoted
(`jnp.result_type(A, b)`) on every backend.

References: M. B. Giles, "Collected matrix derivative results for forward and reverse mode
algorithmic differentiation" (2008), for `A_bar = -lambda x^T`; lineax (P. Kidger et al.) for the
results convention; Y. Chen, T. A. Davis et al., "CHOLMOD" (2008); X. S. Li, "An overview of
SuperLU" (2005).
SciPy: `scipy.sparse.linalg.spsolve` / `splu` / `cg`; libigl: `min_quad_with_fixed` for the
Dirichlet blocks.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import warnings
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Inexact, Int

from .._compile import at_top_level, device_array, kernel
from .._errors import DDGInputError, check_choice, is_traced
from .._options import LINEAR_SOLVERS
from .._results import RESULTS, Record, first_failure, is_failure, raise_if_failed
from ..sparse import SparseMatrix, SparsityPattern
from ._amg import AMGHierarchy, amg_hierarchy, amg_v_cycle
from ._host import HOST_METHODS, host_factor, host_solve

PRECONDITIONERS = ("jacobi", "amg")

# Above this many unknowns `"auto"` without CHOLMOD prefers pyamg's CG to SuperLU: on mesh Laplacians
# SuperLU's factor + solve takes ~1 s at 41k and ~8 s at 164k, pyamg's setup + CG 0.4 s and 0.9 s.
SUPERLU_LIMIT = 50_000

# Above this many unknowns one solve (`linear_solve`) with `"auto"` runs pyamg's CG rather than a factorisation.
# CHOLMOD's fill makes its cost grow like n^1.4 on surfaces (faster on 3-D graphs), pyamg's set-up + CG like
# n^1.1; where they cross depends on the mesh (icosphere: below 41k; armadillo: above 700k), and from here
# on the first is ~5x faster where it wins, the second at most ~1.3x (benchmarks/README.md, "Laplacian
# systems at scale"). Kept factorisations (`factorize`) stay direct: many solves share their cost.
ITERATIVE_LIMIT = 500_000

# A matrix with more stored entries per row than this is taken for a volume (a triangle mesh's rows hold
# ~7, a 3-D neighbourhood graph's or a tetrahedral mesh's 12-16), whose factor fills in like n^(4/3) and
# whose factorisation costs like n^2: one solve turns to pyamg's CG from `VOLUME_ITERATIVE_LIMIT`
# unknowns (10-NN graph in the unit cube, 40k unknowns: CHOLMOD 1.2 s, pyamg 0.22 s).
VOLUME_ENTRIES_PER_ROW = 10
VOLUME_ITERATIVE_LIMIT = 20_000

# Kept CHOLMOD factorisations up to this many unknowns are analysed simplicial (`cholmod_analysis`): up to
# here a simplicial factorisation costs little more than a supernodal one and its solves are faster; above
# it the factorisation falls far behind (measured: benchmarks/README.md, "Kept factorisations").
SIMPLICIAL_LIMIT = 50_000


class PrecisionWarning(UserWarning):
    """A solve runs in float32 (module docstring, "Precision"): shown once per process."""


@functools.cache
def _warn_low_precision() -> None:
    """Warn, once per process, that a float32 system reached a solver (module docstring, "Precision")."""
    warnings.warn(
        "ddgjax.solve: solving a float32 system (JAX's default precision while `jax_enable_x64` is off). "
        "Mesh matrices in float32 carry round-off of ~1e-7 relative, so a well-posed solve can be reported "
        "`singular` (its residual above `residual_tolerance`) or `not_positive_definite`, and its answer "
        'holds a few digits; ddgjax\'s geometry wants float64: `jax.config.update("jax_enable_x64", True)` '
        "at start-up, before arrays are made. Shown once per process.",
        PrecisionWarning,
        stacklevel=3,
    )


class LinearSolution(Record):
    """The answer of `linear_solve`: the solution, the outcome and what the solver did.

    Attributes:
        value: `x`, the shape of `b` (`(n,)` or `(n, k)`), complex when `A` or `b` is.
        result: an item of `ddgjax.RESULTS` (`RESULTS.successful` when `x` solves the system).
        residual: `|A x - b| / |b|` (Frobenius norms for a block `b`; 0 for `b = 0`).
        num_steps: CG iterations (the largest over the columns of a block); 0 for a direct solve.
        solver: the backend that ran (static).
    """

    value: Inexact[Array, "n *k"]
    result: RESULTS
    residual: Float[Array, ""]
    num_steps: Int[Array, ""]
    solver: str = eqx.field(static=True)

    @property
    def stats(self) -> dict[str, Array]:
        """`{"residual": ..., "num_steps": ...}`: the `stats` of a `ddgjax.Solution` whose value came from this solve."""
        return {"residual": self.residual, "num_steps": self.num_steps}


def linear_solve(
    A: SparseMatrix,
    b: Inexact[ArrayLike, "n *k"],
    /,
    *,
    solver: str = "auto",
    preconditioner: str | AMGHierarchy | None = None,
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
    throw: bool = True,
) -> LinearSolution:
    r"""Solve `A x = b` for a symmetric (or complex Hermitian) positive definite `SparseMatrix` `A`, differentiably.

    $$A x = b, \qquad A = A^{H} \succ 0$$

    Args:
        A: `(n, n)` `SparseMatrix` flagged symmetric, or complex and flagged Hermitian (e.g.
            `cotan_laplacian`, `mass_matrix`, `M + t * L`, a free-free Dirichlet block); positive
            definite by the caller's promise.
        b: `(n,)` or `(n, k)` right-hand side(s), real or complex.
        solver: the backend, one of `ddgjax.LINEAR_SOLVERS`: `"cholesky"`, `"superlu"`, `"cg"`,
            `"pyamg"` or `"auto"` (default; module docstring, with the table of which systems each
            accepts: an indefinite `A` fails on `"cholesky"` only).
        preconditioner: for `"cg"`: `"jacobi"` (default), `"amg"` (a smoothed-aggregation hierarchy
            built on the host from `A`'s concrete values) or an `AMGHierarchy` from `amg_hierarchy`
            (built once outside `jit`, passed in; for a complex `A`, of its real form above). Giving
            one with `solver="auto"` selects `"cg"`.
        rtol: relative tolerance of the CG methods (`|r| <= rtol |b|`); the direct solves ignore it.
        max_steps: CG iteration limit (default `10 n`).
        residual_tolerance: a solution with a larger relative residual is reported as `singular`.
        throw: raise on failure (default) or return the `LinearSolution` to inspect (module
            docstring: what fails, and how it raises).

    Returns:
        `LinearSolution` with `value` the shape of `b`, of dtype `jnp.result_type(A, b)`.

    Differentiable in `b` and `A.values` (module docstring), under `jit`, `grad`, `vmap` and inside
    `lax.scan`. Equal to `factorize(A, ...).solve(b)`. SciPy: `scipy.sparse.linalg.spsolve(A.to_scipy(), b)`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> L, M = ddgjax.laplacian.laplacian_and_mass(ddgjax.mesh.icosphere(2))
        >>> solution = ddgjax.solve.linear_solve(M + 0.1 * L, M @ jnp.ones(162))
        >>> bool(jnp.allclose(solution.value, 1.0)), bool(solution.residual < 1e-10)
        (True, True)
    """
    _check_matrix(A)
    _check_rhs(A, b)
    with cholmod_analysis("auto"):  # one solve: CHOLMOD's choice factors fastest (`cholmod_analysis`)
        factorization = _factorize(
            A,
            solver=solver,
            preconditioner=preconditioner,
            rtol=rtol,
            max_steps=max_steps,
            residual_tolerance=residual_tolerance,
            one_shot=True,
        )
    return factorization.solve(b, throw=throw)


class Factorization(eqx.Module):
    """A factorisation of a symmetric (Hermitian) positive definite `SparseMatrix`, kept for many right-hand sides.

    Made by `factorize(A, solver=...)`; `factorization.solve(b)` solves `A x = b` reusing it, with
    the same differentiation rules as `linear_solve` (tangent and adjoint solves reuse the factor).
    What is kept: for `"cholesky"` the numeric CHOLMOD factor, held by `sparsax` and referenced by
    `token` (its cache keeps a bounded number of factors per sparsity pattern,
    `sparsax.set_num_cache_size`; a token whose factor was evicted raises when used, it never
    answers wrongly); for `"superlu"` and `"pyamg"` the SuperLU factors or the pyamg hierarchy on
    the host, under `token` (an evicted one is made again); for `"cg"` the AMG `hierarchy` (or only
    the Jacobi diagonal, computed in `solve`).

    Attributes:
        system: the real symmetric matrix that is solved: `A` itself, or the real form of a complex `A`
            (module docstring).
        token: the host factor's reference (`"cholesky"`, `"superlu"`, `"pyamg"`), else `None`.
        hierarchy: the AMG hierarchy of `system` (`"cg"` with an AMG preconditioner), else `None`.
        result: the factorisation's outcome, an item of `ddgjax.RESULTS`: `nonfinite` (NaN or inf in
            `A`), `not_positive_definite` (CHOLMOD), `singular` (SuperLU: exactly singular), else
            `successful`. Every solve with a failed factorisation reports it and returns NaN.
        solver: the backend, one of `LINEAR_SOLVERS` (static, as are the four below).
        complex_dtype: `A`'s dtype when `A` is complex, else `None`.
        rtol: the relative residual tolerance of `"cg"` and `"pyamg"`.
        max_steps: their iteration limit.
        residual_tolerance: the relative residual above which a direct solve reports failure.
    """

    system: SparseMatrix
    token: Int[Array, "..."] | None
    hierarchy: AMGHierarchy | None
    result: RESULTS
    solver: str = eqx.field(static=True)
    complex_dtype: np.dtype | None = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    residual_tolerance: float = eqx.field(static=True)

    def solve(self, b: Inexact[ArrayLike, "n *k"], /, *, throw: bool = True) -> LinearSolution:
        """Solve `A x = b` for `b` of shape `(n,)` or `(n, k)`, reusing the factorisation.

        Returns the `LinearSolution` (raising on failure when `throw`); an eager call runs one
        compiled program per factorisation kind and shape.
        """
        n = self.system.shape[0] // (1 if self.complex_dtype is None else 2)
        solution = _solve(self, _check_rhs_shape(n, b))
        return raise_if_failed(solution, solution.result, throw)


# The outcome is checked by the caller (`raise_if_failed`), so the program holds no run-time check.
@kernel
def _solve(factorization: Factorization, b: Inexact[Array, "n *k"]) -> LinearSolution:
    """`Factorization.solve`'s `LinearSolution` of `A x = b`: the real system, its solve, its outcome."""
    n = factorization.system.shape[0] // (1 if factorization.complex_dtype is None else 2)
    # Mixed dtypes are promoted, as `A @ b` would be (a float32 b with a float64 A is solved in float64).
    dtype = factorization.system.values.dtype if factorization.complex_dtype is None else factorization.complex_dtype
    b = b.astype(jnp.result_type(b.dtype, dtype))
    if factorization.complex_dtype is not None:
        rhs = jnp.concatenate([b.real, b.imag])
    elif jnp.iscomplexobj(b):  # a real A: the real and imaginary parts are two real columns
        rhs = jnp.stack([b.real, b.imag], axis=-1).reshape(n, -1)
    else:
        rhs = b
    value, stats = _solve_factored(factorization, rhs)
    value = jnp.where(is_failure(factorization.result), jnp.nan, value)  # a failed factor answers nothing
    solution = linear_solution(
        factorization.system.__matmul__,
        rhs,
        value,
        stats,
        factorization.solver,
        factorization.residual_tolerance,
        factorization_result=factorization.result,
    )
    if factorization.complex_dtype is not None:
        value = jax.lax.complex(value[:n], value[n:])
    elif jnp.iscomplexobj(b):
        value = value.reshape(b.shape + (2,))
        value = jax.lax.complex(value[..., 0], value[..., 1])
    return eqx.tree_at(lambda s: s.value, solution, value)


def factorize(
    A: SparseMatrix,
    /,
    *,
    solver: str = "auto",
    preconditioner: str | AMGHierarchy | None = None,
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
) -> Factorization:
    r"""Factor a symmetric (Hermitian) positive definite `SparseMatrix` once, for `Factorization.solve(b)` many times.

    $$A = R^{H} R \quad \text{(the Cholesky backend)}, \qquad x = R^{-1} R^{-H} b \quad \text{per right-hand side}$$

    Options as in `linear_solve`. Works inside `jit` (the factor is made when the program runs; an
    AMG preconditioner needs concrete values, or a hierarchy passed in) and differentiably (through
    `Factorization.solve`). Never raises on the values: a factorisation that fails (NaN in `A`, a
    matrix CHOLMOD finds not positive definite, one SuperLU finds singular) is kept in the
    `Factorization`'s `result`, and its solves report it (raising with `throw=True`). Made outside
    `jit`, a CHOLMOD factorisation of up to `SIMPLICIAL_LIMIT` (50,000) unknowns is simplicial, whose
    solves are faster than those of the supernodal one `linear_solve` gets (`cholmod_analysis`).
    SciPy: `scipy.sparse.linalg.splu(A).solve`; cholespy: `CholeskySolverD(...).solve`.

    Args:
        A: `(n, n)` `SparseMatrix` flagged symmetric, or complex and flagged Hermitian; positive definite
            by the caller's promise (as `linear_solve`).
        solver: the backend, one of `ddgjax.LINEAR_SOLVERS` (`"auto"`, the default, `"cholesky"`,
            `"superlu"`, `"cg"`, `"pyamg"`).
        preconditioner: for `"cg"`: `"jacobi"` (default), `"amg"` or an `AMGHierarchy` (`linear_solve`).
        rtol: relative tolerance of the CG solves; the direct solves ignore it.
        max_steps: CG iteration limit (default `10 n`).
        residual_tolerance: a solve with a larger relative residual is reported as `singular`.

    Returns:
        `Factorization`; `factorization.solve(b, throw=...)` returns a `LinearSolution` for `b` of shape
        `(n,)` or `(n, k)`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> L, M = ddgjax.laplacian.laplacian_and_mass(ddgjax.mesh.icosphere(2))
        >>> factorization = ddgjax.solve.factorize(M + 0.1 * L)
        >>> b = M @ jnp.ones(162)
        >>> x1, x2 = factorization.solve(b).value, factorization.solve(2 * b).value
        >>> bool(jnp.allclose(x1, 1.0)), bool(jnp.allclose(x2, 2.0))
        (True, True)
    """
    return _factorize(
        A,
        solver=solver,
        preconditioner=preconditioner,
        rtol=rtol,
        max_steps=max_steps,
        residual_tolerance=residual_tolerance,
        one_shot=False,
    )


def _factorize(A, *, solver, preconditioner, rtol, max_steps, residual_tolerance, one_shot: bool) -> Factorization:
    """`factorize`; `one_shot` (`linear_solve`'s single solve) lets `"auto"` choose by size (`auto_solver`)."""
    _check_matrix(A)
    complex_dtype = A.values.dtype if jnp.iscomplexobj(A.values) else None
    system = _real_form(A) if complex_dtype is not None else A
    entries = A.pattern.n_entries if A.pattern.n_entries is not None else A.pattern.nnz
    solver, preconditioner = _choose(solver, preconditioner, system, one_shot=one_shot, entries_per_row=entries / A.shape[0])
    if max_steps is None:
        max_steps = 10 * A.shape[0]
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise DDGInputError(f"max_steps: expected an integer >= 1, got {max_steps!r}")
    if jnp.finfo(system.values.dtype).bits < 64:
        _warn_low_precision()
    values = jax.lax.stop_gradient(system.values)
    token, hierarchy = None, None
    eager = at_top_level() and not is_traced(values)
    # Kept factorisations simplicial (the faster solves), one-shot ones as CHOLMOD chooses (the faster factorisation).
    analysis = _CHOLMOD_ANALYSIS.get() or (kept_analysis(system.shape[0]) if eager and not one_shot else "auto")
    if solver == "cholesky" and eager:
        _release_cholmod_patterns()
        pattern, kept_values = _analysed_apart(system.pattern, values, analysis)
        # Checked here rather than by a callback inside the program: JAX never frees a compiled
        # program that holds a host callback (benchmarks/README.md, "Memory over a stream of meshes").
        with cholmod_analysis(analysis):
            definite = _cholmod_definite_now(pattern, kept_values)
        token, result = _factor(pattern, kept_values, definite, solver=solver)
    elif solver == "cholesky":
        token, result = _factor(*_analysed_apart(system.pattern, values, analysis), None, solver=solver)
    elif solver in HOST_METHODS:
        token, result = _factor(system.pattern, values, None, solver=solver)
    else:
        result = RESULTS.where(jnp.all(jnp.isfinite(values)), RESULTS.successful, RESULTS.nonfinite)
    if isinstance(preconditioner, AMGHierarchy):
        if preconditioner.shape != system.shape:
            raise DDGInputError(
                f"preconditioner: an AMGHierarchy of shape {preconditioner.shape} for a system of shape {system.shape}"
                + (" (a complex A is solved in its real form of twice the size)" if complex_dtype is not None else "")
            )
        hierarchy = preconditioner
    elif preconditioner == "amg" and not is_failure(result):  # values are concrete here (`_choose`)
        hierarchy = amg_hierarchy(SparseMatrix(values, system.pattern, symmetric=True))
    factorization = Factorization(
        system=system,
        token=token,
        hierarchy=hierarchy,
        result=result,
        solver=solver,
        complex_dtype=complex_dtype,
        rtol=float(rtol),
        max_steps=int(max_steps),
        residual_tolerance=float(residual_tolerance),
    )
    if solver == "cholesky" and eager:
        _track_cholmod(token)
    return factorization


def _check_matrix(A) -> None:
    if not isinstance(A, SparseMatrix):
        raise DDGInputError(
            f"A: expected a ddgjax SparseMatrix (e.g. cotan_laplacian(mesh) or ddgjax.sparse.from_scipy(matrix)), "
            f"got {type(A).__name__}"
        )
    n_rows, n_cols = A.shape
    if n_rows != n_cols:
        raise DDGInputError(f"A: expected a square matrix, got shape {A.shape}")
    if not A.self_adjoint:
        raise DDGInputError(
            "A: expected a symmetric matrix (flagged `symmetric`, as the Laplacian and mass matrices are), or a complex "
            "one flagged `hermitian`; linear_solve solves symmetric (Hermitian) positive definite systems"
        )
    if A.pattern.nnz < n_rows:
        raise DDGInputError(
            f"A: stores {A.pattern.nnz} entries for {n_rows} rows, so some row is empty and A is singular; "
            "a positive definite matrix stores its whole diagonal"
        )


def _check_rhs(A: SparseMatrix, b) -> None:
    _check_rhs_shape(A.shape[0], b)


def _check_rhs_shape(n: int, b) -> Inexact[Array, "n *k"]:
    if np.ndim(b) not in (1, 2) or np.shape(b)[0] != n:
        raise DDGInputError(f"b: expected shape ({n},) or ({n}, k), got {np.shape(b)}")
    return device_array(b)


def _choose(
    solver, preconditioner, system: SparseMatrix, *, one_shot: bool, entries_per_row: float = 7.0
) -> tuple[str, str | AMGHierarchy | None]:
    """The backend and the CG preconditioner that run, `"auto"` resolved (module docstring), or `DDGInputError`."""
    check_choice("solver", solver, LINEAR_SOLVERS)
    if preconditioner is not None and not isinstance(preconditioner, AMGHierarchy):
        check_choice("preconditioner", preconditioner, PRECONDITIONERS)
    if solver == "auto":
        solver = auto_solver(system.shape[0], preconditioner is not None, one_shot=one_shot, entries_per_row=entries_per_row)
        if solver == "cg" and preconditioner is None:
            preconditioner = "jacobi" if is_traced(system.values) else "amg"
    if solver != "cg" and preconditioner is not None:
        raise DDGInputError(f"preconditioner: only solver='cg' takes a preconditioner; solver={solver!r} does not")
    if solver == "cholesky" and not jax.config.jax_enable_x64:
        raise DDGInputError(
            "solver: 'cholesky' works in float64, which JAX has off; enable it with "
            "jax.config.update('jax_enable_x64', True), or use solver='superlu' or 'cg'"
        )
    if solver == "cholesky" and not _has_sparsax():
        raise DDGInputError(
            "solver: 'cholesky' needs the sparsax package (CHOLMOD through XLA FFI), which is not installed; "
            'install it with `pip install "ddgjax[cholmod]"` (its wheels bundle GPL-2+ CHOLMOD code), or use '
            "solver='superlu' (SciPy) or 'cg'"
        )
    if preconditioner == "amg" and is_traced(system.values):
        raise DDGInputError(
            "preconditioner: 'amg' builds its hierarchy on the host from concrete matrix values, and these are traced; "
            "build it outside jit with ddgjax.solve.amg_hierarchy(A) and pass preconditioner=hierarchy "
            "(amg_refresh updates it inside jit), or use preconditioner='jacobi'"
        )
    return solver, "jacobi" if solver == "cg" and preconditioner is None else preconditioner


def auto_solver(n: int, preconditioned: bool = False, *, one_shot: bool = False, entries_per_row: float = 7.0) -> str:
    """The backend `solver="auto"` runs for `n` unknowns (module docstring): `"cg"` when a preconditioner is
    given or on an accelerator; for one solve (`linear_solve`, `one_shot`) of more than `ITERATIVE_LIMIT`
    unknowns, or of more than `VOLUME_ITERATIVE_LIMIT` with more than `VOLUME_ENTRIES_PER_ROW` stored entries
    per row of `A` (a complex `A`'s own rows), `"pyamg"`; else `"cholesky"` where `sparsax` is installed
    and float64 is on, else `"superlu"` up to `SUPERLU_LIMIT` unknowns and `"pyamg"` above."""
    if preconditioned or jax.default_backend() != "cpu":
        return "cg"
    volume_like = entries_per_row > VOLUME_ENTRIES_PER_ROW
    if one_shot and n > (VOLUME_ITERATIVE_LIMIT if volume_like else ITERATIVE_LIMIT):
        return "pyamg"
    if _has_sparsax() and jax.config.jax_enable_x64:
        return "cholesky"
    return "superlu" if n <= SUPERLU_LIMIT else "pyamg"


@kernel  # eagerly one kept program, not a dozen op-by-op compilations
def _real_form(A: SparseMatrix) -> SparseMatrix:
    """The real symmetric `(2n, 2n)` matrix `[[Re A, -Im A], [Im A, Re A]]` of a complex Hermitian `A` (module docstring).

    On a COO pattern of the four blocks' copies of `A`'s slots, built with JAX operations, so it
    works on traced patterns too; linear in `A.values`.
    """
    pattern, n = A.pattern, A.shape[0]
    rows = jnp.concatenate([pattern.rows, pattern.rows, pattern.rows + n, pattern.rows + n])
    cols = jnp.concatenate([pattern.cols, pattern.cols + n, pattern.cols, pattern.cols + n])
    real_pattern = SparsityPattern(rows=rows, cols=cols, indptr=None, shape=(2 * n, 2 * n), layout="coo", symmetric=True)
    re, im = A.values.real, A.values.imag
    values = jnp.concatenate([re, -im, im, re])
    return SparseMatrix(values, real_pattern, symmetric=True, positive_semidefinite=A.positive_semidefinite)


def linear_solution(
    apply,
    b,
    value,
    stats,
    solver: str,
    residual_tolerance: float,
    *,
    factorization_result: RESULTS = RESULTS.successful,
) -> LinearSolution:
    """The `LinearSolution` of a computed `value` of `A x = b` (`apply(x) = A x`): its residual and outcome
    (`RESULTS`); `stats = (num_steps, converged, factored)`, the factorisation's own outcome first.
    Shared with the sharded CG (`ddgjax.sharding`)."""
    b_norm = jnp.linalg.norm(b)
    residual = jnp.where(b_norm > 0, jnp.linalg.norm(apply(value) - b) / jnp.where(b_norm > 0, b_norm, 1.0), 0.0)
    num_steps, converged, factored = (device_array(stat) for stat in stats)
    # A NaN in b stops CG at once (no comparison with NaN holds), so b is checked, not only x.
    finite = jnp.all(jnp.isfinite(value)) & jnp.all(jnp.isfinite(b))
    solve_result = RESULTS.where(
        ~factored,
        RESULTS.singular,
        RESULTS.where(
            ~finite,
            RESULTS.nonfinite,
            RESULTS.where(
                ~converged,
                RESULTS.max_steps_reached,
                RESULTS.where(residual > residual_tolerance, RESULTS.singular, RESULTS.successful),
            ),
        ),
    )
    result = first_failure(factorization_result, solve_result)
    return LinearSolution(value=value, result=result, residual=residual, num_steps=num_steps, solver=solver)


@kernel(static_argnames=("solver",))
def _factor(
    pattern: SparsityPattern, values: Float[Array, " nnz"], definite: Bool[ArrayLike, ""] | None, *, solver: str
) -> tuple[Int[Array, "..."], RESULTS]:
    """The host factor's token of the matrix with `values` on `pattern` and the factorisation's outcome:
    CHOLMOD's (`sparsax.factor`, in float64) for `"cholesky"`, else SuperLU's or pyamg's (`host_factor`);
    one compiled program per pattern.

    What cannot be factored never reaches the factorisation, which would raise from the XLA runtime
    (CHOLMOD) or the host (pyamg): the identity stands in for a matrix with NaN or inf values, and
    for one that CHOLMOD's check finds not positive definite (`_cholmod_definite`); the outcome says
    which (`Factorization.result`).
    """
    finite = jnp.all(jnp.isfinite(values))
    values = jnp.where(finite, values, (pattern.rows == pattern.cols).astype(values.dtype))
    if solver != "cholesky":
        token = host_factor(solver, pattern, values)
        factored = RESULTS.where(token >= 0, RESULTS.successful, RESULTS.singular)
    else:
        import sparsax

        n, values = pattern.shape[0], values.astype(jnp.float64)
        if definite is None:  # values traced: checked by a host callback when the program runs
            definite = _cholmod_definite(pattern, values)
        # CHOLMOD's stand-in is the identity on slots `(k mod n, k mod n)` (repeats are summed), which
        # does not need the pattern to store its diagonal; a pattern with fewer slots than rows holds no
        # positive definite matrix (it is refused by `factorize`).
        diagonal = jnp.arange(pattern.nnz, dtype=pattern.rows.dtype) % n
        rows, cols = (jnp.where(definite, index, diagonal) for index in (pattern.rows, pattern.cols))
        # CHOLMOD reads the upper triangle of the COO list (rows <= cols) and sums repeated positions,
        # so the storage slots go in as they are (ELL padding adds zeros).
        token = sparsax.factor(rows, cols, jnp.where(definite, values, 1.0), n)
        factored = RESULTS.where(definite, RESULTS.successful, RESULTS.not_positive_definite)
    return token, RESULTS.where(finite, factored, RESULTS.nonfinite)


def kept_analysis(n: int) -> str:
    """The CHOLMOD analysis of a kept factorisation of `n` unknowns: `"simplicial"` up to `SIMPLICIAL_LIMIT`, else `"auto"`."""
    return "simplicial" if n <= SIMPLICIAL_LIMIT else "auto"


# The CHOLMOD analysis of the factorisations made in this context (`cholmod_analysis`); unset: `factorize`'s default.
_CHOLMOD_ANALYSIS: contextvars.ContextVar[str | None] = contextvars.ContextVar("ddgjax_cholmod_analysis", default=None)
_CHOLMOD_MODES = {"simplicial": 0, "auto": 1}


@contextlib.contextmanager
def cholmod_analysis(mode: str):
    """Analyse the CHOLMOD factorisations made (or, inside `jit`, run) in this block `"simplicial"`ly or as CHOLMOD chooses (`"auto"`).

    A simplicial factor's solves are faster than a supernodal one's on mesh Laplacians, its factorisation
    as fast at ~10k unknowns and slower beyond (benchmarks/README.md, "Kept factorisations"): kept factorisations (`factorize` called outside `jit`, the heat solver's solver,
    Large Steps) are simplicial up to `SIMPLICIAL_LIMIT` unknowns (`kept_analysis`), one-shot solves
    (`linear_solve`) and larger systems CHOLMOD's choice (supernodal from a few thousand unknowns). `sparsax` fixes the choice per pattern when it first analyses it, process-wide
    (`sparsax_cpp.set_supernodal`, which `sparsax.set_options` sets and then empties its cache), so
    the mode is set for the block and a simplicial factorisation goes in with one explicit zero more on
    the diagonal, a pattern of its own (`_analysed_apart`), never sharing a supernodal one's analysis.
    A program that factorises inside this block must also run in it (block on its result).
    """
    check_choice("mode", mode, tuple(_CHOLMOD_MODES))
    outer = _CHOLMOD_ANALYSIS.get() or "auto"
    context = _CHOLMOD_ANALYSIS.set(mode)
    setter = _supernodal_setter()
    if setter is not None:
        setter(_CHOLMOD_MODES[mode])
    try:
        yield
    finally:
        if setter is not None:
            setter(_CHOLMOD_MODES[outer])
        _CHOLMOD_ANALYSIS.reset(context)


@functools.cache
def _supernodal_setter():
    """`sparsax_cpp.set_supernodal`, or `None` where `sparsax` is absent or has no such switch (then CHOLMOD chooses)."""
    try:
        import sparsax_cpp
    except ImportError:
        return None
    return getattr(sparsax_cpp, "set_supernodal", None)


def _analysed_apart(pattern: SparsityPattern, values: Float[Array, " nnz"], analysis: str):
    """`(pattern, values)` as CHOLMOD takes them: for a simplicial analysis, with one explicit zero added at
    `(0, 0)` (summed into the diagonal: the same matrix), so `sparsax` caches its analysis apart (`cholmod_analysis`)."""
    if analysis != "simplicial":
        return pattern, values
    return _with_zero_at_origin(pattern, values)


@kernel  # eagerly one kept program, not four op-by-op compilations
def _with_zero_at_origin(pattern: SparsityPattern, values: Float[Array, " nnz"]):
    """`_analysed_apart`'s simplicial case: one explicit zero appended at `(0, 0)`."""
    zero = jnp.zeros(1, pattern.rows.dtype)
    apart = SparsityPattern(
        rows=jnp.concatenate([pattern.rows, zero]),
        cols=jnp.concatenate([pattern.cols, zero]),
        indptr=None,
        shape=pattern.shape,
        layout="coo",
        symmetric=True,
    )
    return apart, jnp.concatenate([values, jnp.zeros(1, values.dtype)])


#: Sparsity patterns `sparsax` may hold (each its symbolic analysis and factors, ~3 MB at a few thousand
#: vertices; it has no per-pattern eviction) before ddgjax releases them all, which it does only while
#: no factorisation made outside `jit` is alive, so no kept token goes stale.
CHOLMOD_PATTERNS = 8
_live_cholmod_factorizations = 0


def _track_cholmod(token: Array) -> None:
    """Count a CHOLMOD factorisation made outside `jit` while its token is alive (`_release_cholmod_patterns`).

    The token array, not the `Factorization`: pytree operations (`eqx.tree_at`, `jax.tree.map`) rebuild
    the module around the same leaves, so the module may die while a copy still holds the token.
    """
    global _live_cholmod_factorizations
    _live_cholmod_factorizations += 1
    weakref.finalize(token, _forget_cholmod)


def _forget_cholmod() -> None:
    global _live_cholmod_factorizations
    _live_cholmod_factorizations -= 1


def _release_cholmod_patterns() -> None:
    """Free `sparsax`'s factors once it holds `CHOLMOD_PATTERNS` patterns and no factorisation that uses them is alive.

    A stream of meshes of new connectivities, each solved and dropped, then keeps a bounded number of
    patterns; a kept `Factorization` (a heat-solver solver, a flow's factor) keeps them all, so its
    token stays valid. Tokens made inside a `jit` and returned from it are not counted: keep such a
    factorisation by making it outside `jit`.
    """
    import sparsax

    if _live_cholmod_factorizations == 0 and sparsax.cache_size() >= CHOLMOD_PATTERNS:
        sparsax.clear_cache()


def _cholmod_definite_now(pattern: SparsityPattern, values: Float[Array, " nnz"]) -> np.bool_:
    """`_cholmod_definite` of what `_factor` factors, on concrete values, on the host now."""
    rows, cols, host = np.asarray(pattern.rows), np.asarray(pattern.cols), np.asarray(values, np.float64)
    if not np.all(np.isfinite(host)):
        host = (rows == cols).astype(np.float64)  # `_factor`'s replacement of a non-finite matrix
    return _definite_on_host(rows, cols, host, pattern.shape[0])


def _definite_on_host(rows: ArrayLike, cols: ArrayLike, values: ArrayLike, n: int) -> np.bool_:
    """Whether CHOLMOD factors the float64 matrix (`sparsax_cpp.logdet_np`, which fills `sparsax`'s cache)."""
    import sparsax_cpp

    try:
        sparsax_cpp.logdet_np(
            np.ascontiguousarray(rows, np.int32), np.ascontiguousarray(cols, np.int32), np.ascontiguousarray(values), n
        )
    except RuntimeError as error:  # "sparsax: matrix is not positive definite (failure at column j)"
        if "not positive definite" not in str(error):
            raise
        return np.bool_(False)
    return np.bool_(True)


def _cholmod_definite(pattern: SparsityPattern, values: Float[Array, " nnz"]) -> Bool[Array, ""]:
    """Whether CHOLMOD factors the float64 matrix `values` on `pattern` (a host call that catches its failure).

    The numeric factor it makes stays in `sparsax`'s value-keyed cache, which the `sparsax.factor` call
    that follows hits: one factorisation in all. `sparsax_cpp.logdet_np` is the NumPy entry point
    `sparsax` itself uses for its PyTensor ops.
    """
    n = pattern.shape[0]  # not `pattern` itself: the callback must hold no tracer

    def definite(rows, cols, values):
        return _definite_on_host(rows, cols, values, n)

    shape = jax.ShapeDtypeStruct((), jnp.bool_)
    return jax.pure_callback(definite, shape, pattern.rows, pattern.cols, values, vmap_method="sequential")


def _cholmod_solve(token: Int[Array, "2"], rhs: Float[Array, "n *k"]) -> Float[Array, "n *k"]:
    """`sparsax.solve_factor(token, rhs)` (float64), under any `vmap` (`_cholmod_solve_stacked`)."""
    return _cholmod_solve_stacked(token[None], rhs[None])[0]


@jax.custom_batching.custom_vmap
def _cholmod_solve_stacked(tokens: Int[Array, "m 2"], rhs: Float[Array, "m n *k"]) -> Float[Array, "m n *k"]:
    """`sparsax.solve_factor(tokens[i], rhs[i])` for every `i`, in one batched CHOLMOD call.

    `sparsax`'s own batching rule needs a batched right-hand side (under `vmap` over the matrix
    values only, the tokens are batched and `rhs` is not) and supports one level of `vmap`; this rule
    broadcasts what is not batched and folds every level into the one leading axis.
    """
    import sparsax

    return jax.vmap(sparsax.solve_factor)(tokens, rhs)


@_cholmod_solve_stacked.def_vmap
def _cholmod_solve_stacked_batched(axis_size: int, in_batched, tokens, rhs):
    tokens, rhs = (x if batched else jnp.broadcast_to(x, (axis_size, *x.shape)) for x, batched in zip((tokens, rhs), in_batched))
    flat = _cholmod_solve_stacked(tokens.reshape(-1, *tokens.shape[2:]), rhs.reshape(-1, *rhs.shape[2:]))
    return flat.reshape(rhs.shape), True


@functools.cache
def _has_sparsax() -> bool:
    try:
        import sparsax  # noqa: F401
    except ImportError:
        return False
    return True


def _solve_factored(factorization: Factorization, b):
    """`(x, (num_steps, converged, factored))` with `x = A^{-1} b`, differentiable through `lax.custom_linear_solve`.

    JAX differentiates `custom_linear_solve` implicitly: the derivative of `x` comes from `A`'s
    product (`dx = A^{-1} (db - dA x)`), and the transposed solve (reverse mode) calls the same
    backend, which is `A` itself as `A` is symmetric: one factor serves the forward, the tangent and
    the adjoint solves. The backend itself is never differentiated.
    """
    A, token, solver = factorization.system, factorization.token, factorization.solver
    rtol, max_steps = factorization.rtol, factorization.max_steps
    values = jax.lax.stop_gradient(A.values)
    succeeded = (jnp.zeros((), jnp.int32), jnp.ones((), bool), jnp.ones((), bool))
    if solver == "cholesky":
        # CHOLMOD works in float64; a float32 system is solved in float64 and rounded back.
        def backend(_, rhs):
            return _cholmod_solve(token, rhs.astype(jnp.float64)).astype(rhs.dtype), succeeded

    elif solver in HOST_METHODS:

        def backend(_, rhs):
            return host_solve(solver, A.pattern, values, token, rhs, rtol, max_steps)

    else:
        fixed = SparseMatrix(values, A.pattern, symmetric=True)
        hierarchy = jax.lax.stop_gradient(factorization.hierarchy)
        if hierarchy is None:
            diagonal = fixed.diagonal()
            inverse = jnp.where(diagonal > 0, 1.0 / jnp.where(diagonal > 0, diagonal, 1.0), 1.0)
            preconditioner = lambda r: inverse * r
        else:
            preconditioner = lambda r: amg_v_cycle(hierarchy, r).astype(r.dtype)

        def backend(_, rhs):
            return _block_cg(fixed, rhs, preconditioner, rtol, max_steps)

    return jax.lax.custom_linear_solve(A._product, b, backend, symmetric=True, has_aux=True)


def _block_cg(A: SparseMatrix, b, preconditioner, rtol: float, max_steps: int):
    """`preconditioned_cg` on `A @ x`; a block `b` column by column (`vmap`)."""

    def one(column):
        x, (steps, converged) = preconditioned_cg(A._product, column, preconditioner, rtol, max_steps)
        return x, (steps, converged, jnp.ones((), bool))

    if b.ndim == 1:
        return one(b)
    values, (steps, converged, factored) = jax.vmap(one, in_axes=1, out_axes=(1, 0))(b)
    return values, (jnp.max(steps), jnp.all(converged), jnp.all(factored))


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
