"""Learning functions on graphs: harmonic interpolation (label propagation) and Tikhonov smoothing.

Harmonic interpolation (Zhu, Ghahramani & Lafferty 2003) minimises the graph Dirichlet energy
`1/2 f^T L f = 1/2 sum_edges w_ij (f_i - f_j)^2` with `f` given on the labelled ("fixed") vertices:

    L_uu f_u = -L_ul f_l,

so every free vertex is the weighted mean of its neighbours, `f_i = sum_j w_ij f_j / sum_j w_ij`
(the fixed point of label propagation). With one column per class (`(n_fixed, k)` one-hot values)
the `k` problems share one factorisation and the predicted class is the argmax of the row. A
connected component without a fixed vertex has only the constants as harmonic functions: it gets 0,
as `ddgjax.pde.harmonic_interpolation` gives a mesh component without a fixed vertex (one vertex of
it is held at 0 in the solve; isolated vertices are such components). An edge of weight 0 joins nothing:
a piece that only zero-weight edges connect to the fixed vertices is such a component too (weights known
on the host; traced inside `jit`, such a cut leaves the system singular, reported through `throw=`).

Tikhonov smoothing solves `(I + alpha L) f = y`: the minimiser of
`|f - y|^2 + alpha f^T L f`, a low-pass filter with response `1 / (1 + alpha lambda)` on the
Laplacian's eigenvectors (Smola & Kondor 2003; Belkin, Matveeva & Niyogi 2004).

Both solve with `ddgjax.solve.linear_solve` (`solver=` its backend), differentiable in the edge weights,
the fixed values / signal and `alpha` by implicit differentiation; a failed solve is an outcome
(`throw=`, `ddgjax.RESULTS`): with `throw=False` the answer is a `ddgjax.Solution` whose `stats` are
the solve's relative `residual` and `num_steps`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_vertex_indices, is_traced
from .._options import check_solver
from .._results import RESULTS, Solution, outcome
from ..solve import linear_solve
from ..sparse import DirichletPlan, NonNegative, dirichlet_blocks, dirichlet_plan, nonnegative
from ._laplacian import GraphPlan, GraphStructure, check_weights, graph_structure, laplacian_from_plan, weighted_components

# Dirichlet plans kept per edge list (one per fixed vertex set): re-solving with new values or edge weights skips them.
_PLANS_KEPT = 8


def harmonic_interpolation(
    edges: Int[ArrayLike, "ne 2"],
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"],
    fixed_values: Float[ArrayLike, " n_fixed *k"],
    edge_weights: Float[ArrayLike, " ne"] | None = None,
    n_vertices: int,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "n *k"] | Solution:
    """The harmonic extension of values on some vertices of a graph: label propagation (module docstring).

    Solves `L_uu f_u = -L_ul f_l` (`L = D - W`, `graph_laplacian`) with `f = fixed_values` on
    `fixed_vertices`: each free vertex ends at the weighted mean of its neighbours. A component
    without a fixed vertex gets 0, also one cut off by edges of weight 0. Differentiable in `edge_weights` and `fixed_values`.

    Args:
        edges: `(ne, 2)` undirected edges (host data; `graph_laplacian`).
        fixed_vertices: `(n_fixed,)` distinct labelled vertices, at least one (host data).
        fixed_values: `(n_fixed,)` or `(n_fixed, k)` their values (`k` classes at once, e.g. one-hot labels).
        edge_weights: `(ne,)` positive edge weights (default ones).
        n_vertices: the number of vertices.
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS`.
        throw: raise on a failed solve (default), or return the outcome.

    Returns:
        `f`, `(n_vertices,)` or `(n_vertices, k)`; with `throw=False` a `ddgjax.Solution` (`stats`:
        the solve's `"residual"` and `"num_steps"`).

    Reference: X. Zhu, Z. Ghahramani, J. Lafferty, "Semi-supervised learning using Gaussian fields and
    harmonic functions" (ICML 2003). scikit-learn: `LabelPropagation(kernel="knn")` iterates to the
    same fixed point; libigl's `harmonic` is the mesh version (`ddgjax.pde.harmonic_interpolation`).
    """
    check_solver(solver)
    structure = graph_structure(edges, n_vertices)
    edge_weights = check_weights(edge_weights, structure.n_edges)
    fixed = check_vertex_indices("fixed_vertices", fixed_vertices, structure.n_vertices, minimum=1)
    values = device_array(fixed_values)
    if values.ndim not in (1, 2) or values.shape[0] != fixed.size:
        raise DDGInputError(
            f"fixed_values: expected shape ({fixed.size},) or ({fixed.size}, k) (one row per fixed vertex), got {values.shape}"
        )
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = device_array(fixed_values, edge_weights.dtype)  # host data converted on the host
    plan, n_pinned = _dirichlet(structure, fixed, weighted_components(structure, edge_weights))
    if plan is None:  # every vertex fixed: nothing to solve
        f = jnp.zeros((structure.n_vertices,) + values.shape[1:], values.dtype).at[fixed].set(values)
        return outcome(f, RESULTS.successful, throw, _no_solve_stats(values.dtype))
    f, result, stats = _harmonic(edge_weights, values, structure.plan, plan, n_pinned=n_pinned, solver=solver)
    return outcome(f, result, throw, stats)


def _harmonic(edge_weights, values, graph: GraphPlan, plan: DirichletPlan, *, n_pinned: int, solver: str):
    """`(f, result, stats)` of `harmonic_interpolation`; `plan.fixed` is the fixed vertices, then `n_pinned` pins.

    Called eagerly: `L_uu f_u = -L_ul f_l` comes from one compiled program, `linear_solve` runs its own
    (its definiteness check and outcome on the host, outside them) and one more joins `f`, so every
    program can be kept across processes (`ddgjax._program_store`). Under `jit` / `grad` / `vmap` it is
    all traced into the caller's program.
    """
    free_free, rhs, fixed_values = _harmonic_system(edge_weights, values, graph, plan, n_pinned=n_pinned)
    solution = linear_solve(free_free, rhs, solver=solver, throw=False)
    return _joined(plan, solution.value, fixed_values), solution.result, solution.stats


@kernel(static_argnames=("n_pinned",))
def _harmonic_system(edge_weights, values, graph: GraphPlan, plan: DirichletPlan, *, n_pinned: int):
    """`(L_uu, -L_ul f_l, f_l)`: the free-free block of `L`, the right-hand side, and the held values
    (`values`, then `n_pinned` zeros)."""
    laplacian = laplacian_from_plan(edge_weights, graph)
    dtype = jnp.result_type(laplacian.dtype, values.dtype)
    fixed_values = jnp.concatenate([values.astype(dtype), jnp.zeros((n_pinned,) + values.shape[1:], dtype)])
    free_free, free_fixed = dirichlet_blocks(laplacian, plan)
    return free_free, -(free_fixed @ fixed_values), fixed_values


@kernel
def _joined(plan: DirichletPlan, free_values, fixed_values):
    """`f` with `free_values` at the free vertices and `fixed_values` at the held ones."""
    return plan.join(free_values, fixed_values)


def tikhonov_smoothing(
    edges: Int[ArrayLike, "ne 2"],
    signal: Float[ArrayLike, "n *k"],
    *,
    edge_weights: Float[ArrayLike, " ne"] | None = None,
    n_vertices: int,
    alpha: float | Float[ArrayLike, ""],
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "n *k"] | Solution:
    """Tikhonov (Laplacian-regularised) smoothing of a graph signal: `(I + alpha L) f = y`.

    The minimiser of `|f - y|^2 + alpha f^T L f` (`L = D - W`, `graph_laplacian`): a low-pass filter
    with response `1 / (1 + alpha lambda)` on the eigenvectors of `L`; the mean of `y` on each
    component is kept. Differentiable in `signal`, `edge_weights` and `alpha`.

    Args:
        edges: `(ne, 2)` undirected edges (host data).
        signal: `(n_vertices,)` or `(n_vertices, k)` the signal `y`.
        edge_weights: `(ne,)` non-negative edge weights (default ones).
        n_vertices: the number of vertices.
        alpha: the smoothing strength, `>= 0`: a number (checked here), or a traced JAX scalar
            (checked when the program runs: a negative one raises `ddgjax.RESULTS.negative_value`'s
            message whatever `throw` is, `ddgjax.sparse.nonnegative`).
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS`.
        throw: raise on a failed solve (default), or return the outcome.

    Returns:
        `f`, the shape of `signal`; with `throw=False` a `ddgjax.Solution` (`stats`: the solve's
        `"residual"` and `"num_steps"`).

    Reference: A. Smola, R. Kondor, "Kernels and regularization on graphs" (COLT 2003); the mesh
    analogue is one implicit step of the heat equation. PyGSP: `filters.Filter(G, lambda x: 1 / (1 + alpha x))`.
    """
    check_solver(solver)
    structure = graph_structure(edges, n_vertices)
    edge_weights = check_weights(edge_weights, structure.n_edges)
    n = structure.n_vertices
    if np.ndim(signal) not in (1, 2) or np.shape(signal)[0] != n:
        raise DDGInputError(f"signal: expected shape ({n},) or ({n}, k), got {np.shape(signal)}")
    given, signal = signal, device_array(signal)
    if not jnp.issubdtype(signal.dtype, jnp.floating):
        signal = device_array(given, edge_weights.dtype)  # host data converted on the host
    if np.ndim(alpha) != 0:
        raise DDGInputError(f"alpha: expected a scalar, got shape {np.shape(alpha)}")
    if not is_traced(alpha) and not (np.isfinite(alpha) and alpha >= 0):
        raise DDGInputError(f"alpha: expected a finite number >= 0, got {alpha!r}")
    f, result, stats = _tikhonov(edge_weights, signal, alpha, structure.plan, solver=solver)
    return outcome(f, result, throw, stats)


def _tikhonov(edge_weights, signal, alpha, graph: GraphPlan, *, solver: str):
    """`(f, result, stats)` of `tikhonov_smoothing`: `(I + alpha L) f = y` from one compiled program, then
    `linear_solve` on it (eagerly its own programs, so each can be kept across processes; traced inline
    under a transformation, as `_harmonic`)."""
    system, rhs = _tikhonov_system(edge_weights, signal, alpha, graph, checked=not is_traced(alpha))
    solution = linear_solve(system, rhs, solver=solver, throw=False)
    return solution.value, solution.result, solution.stats


@kernel(static_argnames=("checked",))
def _tikhonov_system(edge_weights, signal, alpha, graph: GraphPlan, *, checked: bool):
    """`(I + alpha L, y)`, `y` in the system's dtype; `checked`: `alpha` is concrete and was checked `>= 0` on the host."""
    # `nonnegative` keeps the PSD flag for a traced alpha and reports a negative one as an outcome; a
    # checked one needs no run-time check (a host callback, which would keep the program from being stored).
    scale = NonNegative(jnp.asarray(alpha)) if checked else nonnegative(alpha)
    system = (scale * laplacian_from_plan(edge_weights, graph)).shifted(1.0)
    return system, signal.astype(system.dtype)


def _dirichlet(
    structure: GraphStructure, fixed: np.ndarray, components: tuple[int, np.ndarray, bytes]
) -> tuple[DirichletPlan | None, int]:
    """`(plan, n_pinned)`: the Dirichlet plan of `[fixed | one pinned vertex per unlabelled component]` (cached
    per fixed set and set of cut edges), the components `(n_components, labels, key)` of `weighted_components`."""
    n_components, labels, cut_key = components
    key = (fixed.tobytes(), cut_key)
    if key in structure.dirichlet:
        return structure.dirichlet[key]
    labelled = np.zeros(n_components, dtype=bool)
    labelled[labels[fixed]] = True
    # The lowest vertex of each component without a fixed vertex is held at 0 (its harmonic functions are constants).
    first = np.full(n_components, structure.n_vertices, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(structure.n_vertices))
    pins = first[~labelled]
    held = np.concatenate([fixed, pins])
    with jax.ensure_compile_time_eval():  # host work even inside a caller's trace
        plan = dirichlet_plan(structure.plan.pattern, held) if held.size < structure.n_vertices else None
    if len(structure.dirichlet) >= _PLANS_KEPT:
        structure.dirichlet.pop(next(iter(structure.dirichlet)))
    structure.dirichlet[key] = (plan, int(pins.size))
    return plan, int(pins.size)


def _no_solve_stats(dtype) -> dict[str, Array]:
    return {"residual": jnp.zeros((), dtype), "num_steps": jnp.zeros((), jnp.int32)}
