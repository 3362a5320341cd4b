"""`minimize_energy`: Newton's method with a sparse Hessian for energies of values on a mesh's vertices.

An energy of vertex values built from per-face (or per-edge) terms, such as the Dirichlet, screened
Dirichlet, Poisson and p-Dirichlet energies, has a Hessian whose sparsity pattern is the mesh's
vertex adjacency: entry `(i, j)` can be nonzero only when `i == j` or `ij` is an edge. For values
`(nv, d)` (a map, positions) each entry is a `d x d` block. `minimize_energy` builds that pattern
for the caller, on the free vertices (fixed vertices are eliminated: they are not unknowns), and
each Newton step

1. recovers the Hessian on the pattern from a few Hessian-vector products, one per colour of a
   distance-2 column colouring, all in one vmapped program (`ddgjax.solve.SparseCholesky`);
2. factorises it once (`ddgjax.solve.factorize`: CHOLMOD by default) and solves for the Newton step;
3. evaluates the gradient at the new point and solves once more with the same factor: this chord
   step (Shamanskii 1967) is both applied, as a free correction, and the convergence test. The run
   stops when it is small, `max_norm(step / (atol + rtol |x|)) < 1` (the test on the iterates of
   `optx.Newton`'s Cauchy termination, on the step it would take next).

So a quadratic energy is minimised by one factorisation: the Newton step lands on the minimiser, and
the chord step (a step of iterative refinement of it) confirms it without a second factorisation,
where `optx.root_find(jax.grad(E), optx.Newton(...))` takes a second Newton step, a second Hessian
and factorisation, to see that the first one converged. For a non-quadratic energy each factorisation
serves two steps (cubic local convergence per factorisation). There is no line search, as in
`optx.Newton`: start close enough, or from anywhere for strictly convex energies such as the
p-Dirichlet energy with a screening term.

Derivatives of the minimiser with respect to `args` and `fixed_values` are by the implicit function
theorem (`optx.ImplicitAdjoint`), with the same sparse Cholesky for the Hessian's solve.

References: P. Deuflhard, *Newton Methods for Nonlinear Problems* (2004), ch. 2 (Newton, and the
simplified Newton / chord step); V. Shamanskii, "A modification of Newton's method" (1967); A. R.
Curtis, M. J. D. Powell, J. K. Reid (1974) and A. H. Gebremedhin, F. Manne, A. Pothen (2005) on
recovering sparse derivative matrices by colouring. optimistix: `optx.minimise`, `optx.Newton`.
"""

from __future__ import annotations

import collections
import hashlib
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree, Scalar

from .._compile import device_array
from .._errors import DDGInputError, check_vertex_indices, is_traced
from .._options import check_solver
from .._results import RESULTS, first_failure, is_failure, raise_if_failed
from ..mesh import Mesh, require_mesh
from ..solve import SparseCholesky
from ..solve.internal import LINEAX_RESULTS
from ..sparse import SparsityPattern


class _Unknowns(eqx.Module):
    """The free values as one vector: `x = full(y, fixed_values)`, the inverse of `y = x[free].ravel()`."""

    position: Int[Array, " nv"]  # row of vertex v in concatenate([free rows, fixed rows])
    trailing: tuple[int, ...] = eqx.field(static=True)

    def full(self, y: Float[Array, " n"], fixed_values: Float[Array, " n_fixed *d"]) -> Float[Array, "nv *d"]:
        rows = jnp.concatenate([y.reshape(-1, *self.trailing), fixed_values.astype(y.dtype)])
        return jnp.take(rows, self.position, axis=0)


class _Energy(eqx.Module):
    """optimistix's `fn(y, args)` of the user's `energy(x, *args)`: a module, so that an eager call with the same
    energy hits `optx.minimise`'s compilation cache."""

    energy: Callable
    unknowns: _Unknowns

    def __call__(self, y, args):
        fixed_values, energy_args = args
        return self.energy(self.unknowns.full(y, fixed_values), *energy_args)


class _SparseNewtonState(eqx.Module):
    converged: Bool[Array, ""]
    failure: RESULTS  # ddgjax's outcome of the step's factorisation and solves


class _SparseNewton(optx.AbstractMinimiser):
    """Newton's method with the Hessian recovered on a sparsity pattern, and a chord step per factorisation (module docstring)."""

    rtol: float
    atol: float
    cholesky: SparseCholesky
    norm: Callable[[PyTree], Scalar] = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        return _SparseNewtonState(converged=jnp.array(False), failure=RESULTS.successful)

    def step(self, fn, y, args, options, state, tags):
        def gradient(z):
            return jax.grad(lambda z: fn(z, args)[0])(z)

        g, hessian_product = jax.linearize(gradient, y)
        operator = lx.FunctionLinearOperator(hessian_product, jax.eval_shape(lambda: y))
        factor = self.cholesky.init(operator, {})  # the colouring's products (vmapped), then the factorisation
        newton = factor.solve(g, throw=False)
        z = y - newton.value
        chord = factor.solve(gradient(z), throw=False)
        failure = first_failure(newton.result, chord.result)
        new_y = jnp.where(is_failure(failure), y, z - chord.value)  # a failed step is not applied
        scale = self.atol + self.rtol * jnp.abs(new_y)
        converged = self.norm(chord.value / scale) < 1
        return new_y, _SparseNewtonState(converged=converged, failure=failure), None

    def terminate(self, fn, y, args, options, state, tags):
        result = optx.RESULTS.successful
        for ours, theirs in LINEAX_RESULTS:
            result = optx.RESULTS.where(state.failure == ours, optx.RESULTS.promote(theirs), result)
        return state.converged | is_failure(state.failure), result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


class _Plan(NamedTuple):
    """What `minimize_energy` builds on the host once per vertex graph, fixed vertices and value shape."""

    free: np.ndarray
    unknowns: _Unknowns
    cholesky: SparseCholesky


# The last few plans (the colouring is host work, growing with the unknowns): solving again on the same
# mesh with the same fixed vertices, new values and a new energy skips it.
_PLANS: collections.OrderedDict = collections.OrderedDict()
_PLANS_KEPT = 8


def minimize_energy(
    energy: Callable[..., Float[Array, ""]],
    x0: Float[ArrayLike, "nv *d"],
    *,
    mesh: Mesh | None = None,
    pattern: SparsityPattern | None = None,
    fixed_vertices: Int[ArrayLike, " n_fixed"] | Sequence[int] | None = None,
    fixed_values: Float[ArrayLike, " n_fixed *d"] | None = None,
    args: tuple = (),
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_steps: int = 256,
    solver: str = "auto",
    throw: bool = True,
) -> optx.Solution:
    r"""Minimise `energy(x, *args)` over vertex values `x` by Newton's method with the sparse Hessian (module docstring).

    $$\nabla^2 E(x_k)\, \Delta x = -\nabla E(x_k), \qquad x_{k+1} = x_k + \Delta x$$

    Example (a harmonic function with boundary values: one factorisation, the direct solve's answer):

        boundary = mesh.topology.boundary_vertices
        solution = minimize_energy(
            lambda u: ddgjax.pde.dirichlet_energy(mesh, u), jnp.zeros(mesh.n_vertices),
            mesh=mesh, fixed_vertices=boundary, fixed_values=g,
        )
        u = solution.value

    The Hessian's pattern is the vertex adjacency of `mesh` (or `pattern`), with full `d x d`
    blocks for `(nv, d)` values, restricted to the free vertices; it is recovered from about 12-15
    Hessian-vector products per step on triangle meshes (`d` times that for `(nv, d)` values) and
    factorised by `ddgjax.solve.factorize`. Each step applies the Newton step and then a chord step
    with the same factor, and the run stops when the chord step is below `atol + rtol |x|` (max
    norm): a quadratic energy takes one step (one factorisation). No line search: the Hessian must
    be positive definite at the iterates (a convex energy, or `x0` near a strict minimum).

    **Dense quasi-Newton methods do not scale to meshes.** `optx.BFGS` (and SciPy's `BFGS`) keep
    a dense `n x n` inverse-Hessian estimate: 1 GB and minutes per run at 11k unknowns, out of
    memory beyond. Use this function when the Hessian has the mesh's pattern; `optx.LBFGS` or
    `optx.NonlinearCG` when it has not (thousands of steps, ~1e-7 accuracy on Poisson problems).

    Args:
        energy: `energy(x, *args) -> scalar`, a JAX-traceable function of `x` (twice differentiable),
            whose Hessian has the pattern above (energies of per-face or per-edge terms do).
        x0: `(nv,)` or `(nv, d)` floating-point starting values; its values at `fixed_vertices` are
            replaced by `fixed_values`.
        mesh: the mesh whose vertex adjacency is the Hessian's pattern (its topology is used, also
            under `jit`).
        pattern: instead of `mesh`, the `(nv, nv)` `SparsityPattern` of the vertex graph (e.g.
            `ddgjax.sparse.from_scipy(A).pattern`; concrete, made outside `jit`).
        fixed_vertices: `(n_fixed,)` distinct vertex indices held fixed (host data), or `None`.
        fixed_values: `(n_fixed,)` / `(n_fixed, d)` their values (may be traced); default: `x0`'s.
        args: a tuple of extra arguments of `energy` (arrays: differentiable, like `fixed_values`).
        rtol, atol: the convergence test on the last step (optimistix's names and max norm).
        max_steps: the most Newton steps (factorisations).
        solver: the backend of the factorisation, one of `ddgjax.LINEAR_SOLVERS` (`"auto"`: CHOLMOD).
        throw: raise when the run fails (default), or report it in `result`.

    Returns:
        `optx.Solution`, as `optx.minimise` returns: `value` the `(nv, *d)` minimiser (the fixed
        values in place), `result` an item of `optx.RESULTS` (`successful`;
        `nonlinear_max_steps_reached`; `singular` when a Hessian was not positive definite or a
        solve failed, in which case `value` is the last good iterate), `stats["num_steps"]` the number
        of Newton steps. With `throw=True` a failure raises with the message of the `ddgjax.RESULTS`
        item (`not_positive_definite`, `max_steps_reached`, ...).

    Raises `DDGInputError` for `x0` not `(nv,)` / `(nv, d)` floating point, for neither or both of
    `mesh` and `pattern`, for `fixed_vertices` out of range, repeated or covering every vertex, for
    `fixed_values` of the wrong shape, and for an `energy` that does not return a floating scalar.

    optimistix: `optx.root_find(jax.grad(E), optx.Newton(rtol, atol, linear_solver=SparseCholesky(pattern)), x0)`
    (two factorisations for a quadratic); SciPy: `scipy.optimize.minimize(E, x0, method="trust-exact")` (dense).

    Examples:
        >>> import numpy as np
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> square = ddgjax.mesh.grid(8, 8)
        >>> x = np.asarray(square.vertices[:, 0])
        >>> sides = np.flatnonzero((x == x.min()) | (x == x.max()))
        >>> solution = ddgjax.optim.minimize_energy(
        ...     lambda u: ddgjax.pde.dirichlet_energy(square, u), jnp.zeros(square.n_vertices),
        ...     mesh=square, fixed_vertices=sides, fixed_values=x[sides],
        ... )
        >>> bool(jnp.allclose(solution.value, x)), int(solution.stats["num_steps"])  # quadratic: one Newton step
        (True, 1)
    """
    x0 = jnp.asarray(x0)
    if x0.ndim not in (1, 2) or not jnp.issubdtype(x0.dtype, jnp.floating):
        raise DDGInputError(
            f"x0: expected an (nv,) or (nv, d) floating-point array of vertex values, got shape {x0.shape} dtype {x0.dtype}"
        )
    if not isinstance(args, tuple):
        raise DDGInputError(f"args: expected a tuple of extra arguments of energy (as SciPy's), got {type(args).__name__}")
    check_solver(solver)
    graph = _vertex_graph(mesh, pattern)
    nv = graph[1]
    if x0.shape[0] != nv:
        raise DDGInputError(f"x0: expected {nv} rows (one per vertex of the mesh / pattern), got shape {x0.shape}")
    fixed = _fixed_indices(fixed_vertices, nv, given_values=fixed_values is not None)
    if fixed_values is None:
        fixed_values = x0[fixed]
    fixed_values = jnp.asarray(fixed_values)
    if fixed_values.shape != (fixed.size, *x0.shape[1:]):
        raise DDGInputError(
            f"fixed_values: expected shape {(fixed.size, *x0.shape[1:])} (one row per fixed vertex, as x0's rows), "
            f"got {fixed_values.shape}"
        )
    out = jax.eval_shape(lambda x, a: energy(x, *a), x0, args)
    if not (isinstance(out, jax.ShapeDtypeStruct) and out.shape == () and jnp.issubdtype(out.dtype, jnp.floating)):
        shown = out if not isinstance(out, jax.ShapeDtypeStruct) else f"shape {out.shape} dtype {out.dtype}"
        raise DDGInputError(f"energy: expected energy(x0, *args) to return a floating-point scalar, got {shown}")
    plan = _plan(graph, fixed, x0.shape[1:], solver)
    minimiser = _SparseNewton(rtol=float(rtol), atol=float(atol), cholesky=plan.cholesky)
    y0 = x0[plan.free].reshape(-1)
    solution = optx.minimise(
        _Energy(energy, plan.unknowns),
        minimiser,
        y0,
        args=(fixed_values, args),
        max_steps=max_steps,
        adjoint=optx.ImplicitAdjoint(linear_solver=plan.cholesky),
        throw=False,
    )
    failure = first_failure(
        solution.state.failure,
        RESULTS.where(solution.result == optx.RESULTS.nonlinear_max_steps_reached, RESULTS.max_steps_reached, RESULTS.successful),
        RESULTS.where(solution.result == optx.RESULTS.nonfinite, RESULTS.nonfinite, RESULTS.successful),
    )
    value = raise_if_failed(plan.unknowns.full(solution.value, fixed_values), failure, throw)
    return optx.Solution(value=value, result=solution.result, aux=solution.aux, stats=solution.stats, state=solution.state)


def _vertex_graph(mesh: Mesh | None, pattern: SparsityPattern | None) -> tuple[Any, int, Callable[[], tuple]]:
    """`(key, nv, edges)`: a cache key of the vertex graph, its size, and a host function listing its `(rows, cols)`."""
    if (mesh is None) == (pattern is None):
        raise DDGInputError(
            "mesh, pattern: pass exactly one: mesh= (the Hessian's pattern is its vertex adjacency) or pattern= "
            "(a SparsityPattern of the vertex graph)"
        )
    if mesh is not None:
        topology = require_mesh("mesh", mesh).topology
        if topology is None:
            raise DDGInputError("mesh: minimize_energy needs the mesh's topology, which a compiled ddgjax kernel does not see")
        edges = np.asarray(topology.edges)
        return ("mesh", topology), topology.n_vertices, lambda: (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])
    if not isinstance(pattern, SparsityPattern) or pattern.shape[0] != pattern.shape[1]:
        raise DDGInputError(
            "pattern: expected the square SparsityPattern of the vertex graph (e.g. cotan_laplacian(mesh).pattern), "
            f"got {type(pattern).__name__}" + (f" of shape {pattern.shape}" if isinstance(pattern, SparsityPattern) else "")
        )
    if is_traced(pattern.rows) or is_traced(pattern.cols):
        raise DDGInputError("pattern: its positions must be concrete (the Hessian's colouring is host work); make it outside jit")
    rows, cols = np.asarray(pattern.rows), np.asarray(pattern.cols)
    digest = hashlib.blake2b(rows.tobytes() + cols.tobytes(), digest_size=16).hexdigest()
    return ("pattern", pattern.shape[0], digest), pattern.shape[0], lambda: pattern.entries()[:2]


def _fixed_indices(fixed_vertices, nv: int, *, given_values: bool) -> np.ndarray:
    """The checked `fixed_vertices` as host int64 indices (empty for `None`), or `DDGInputError`."""
    if fixed_vertices is None:
        if given_values:
            raise DDGInputError("fixed_values: given without fixed_vertices; pass both or neither")
        return np.zeros(0, np.int64)
    fixed = check_vertex_indices("fixed_vertices", fixed_vertices, nv)
    if fixed.size == nv:
        raise DDGInputError("fixed_vertices: every vertex is fixed; nothing is left to minimise over")
    return fixed


def _plan(graph: tuple, fixed: np.ndarray, trailing: tuple[int, ...], solver: str) -> _Plan:
    """The `_Plan` of the free vertices' Hessian pattern (`d x d` blocks for `trailing == (d,)`), cached."""
    key, nv, edges = graph
    cache_key = (key, fixed.tobytes(), trailing, solver)
    plan = _PLANS.get(cache_key)
    if plan is not None:
        _PLANS.move_to_end(cache_key)
        return plan
    d = int(np.prod(trailing, dtype=np.int64))
    is_fixed = np.zeros(nv, bool)
    is_fixed[fixed] = True
    free = np.flatnonzero(~is_fixed)
    position = np.empty(nv, np.int64)
    position[free] = np.arange(free.size)
    position[fixed] = free.size + np.arange(fixed.size)
    rows, cols = (np.asarray(a, np.int64) for a in edges())
    rows, cols = np.r_[rows, free], np.r_[cols, free]  # the diagonal, which a user's pattern may lack
    keep = ~is_fixed[rows] & ~is_fixed[cols]
    rows, cols = position[rows[keep]], position[cols[keep]]
    # Unknown `i d + a` is coordinate `a` of free vertex `i`; every coordinate pair of adjacent vertices may couple.
    block = np.arange(d)
    shape = (rows.size, d, d)
    rows = np.broadcast_to(rows[:, None, None] * d + block[None, :, None], shape).ravel()
    cols = np.broadcast_to(cols[:, None, None] * d + block[None, None, :], shape).ravel()
    with jax.ensure_compile_time_eval():  # host work, also when called inside a caller's trace
        pattern = SparsityPattern.from_coo(rows, cols, (free.size * d, free.size * d))[0]
        unknowns = _Unknowns(position=device_array(position, jnp.int32), trailing=trailing)
        plan = _Plan(free=free, unknowns=unknowns, cholesky=SparseCholesky(pattern, solver=solver))
    _PLANS[cache_key] = plan
    if len(_PLANS) > _PLANS_KEPT:
        _PLANS.popitem(last=False)
    return plan
