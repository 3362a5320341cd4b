"""Fixed-boundary maps of a disk into the plane: Tutte's embedding and the harmonic (cotan) map.

With the boundary loop pinned to positions `b` in the plane, each interior vertex is the weighted
average of its neighbours,

    sum_j w_ij (x_i - x_j) = 0   at interior vertices i,   x = b on the boundary,

i.e. `A_ff x_f = -A_fc b` for the weighted graph Laplacian `A` (`ddgjax.sparse.dirichlet_blocks`),
one sparse solve with two right-hand sides (`ddgjax.solve.linear_solve`, differentiable by implicit
differentiation; its outcome is the map's, `throw=`). The boundary's target is `shape=`: a convex
curve (`"circle"`, `"square"`) or given positions. With positive weights (`"uniform"`, `w_ij = 1`) and the boundary on a convex polygon
the result is a planar embedding without flipped or degenerate triangles (Tutte 1963; Floater 1997),
provided no interior edge joins two boundary vertices on one straight side of the polygon (a strictly
convex boundary such as the circle avoids this). With cotan weights (`"cotan"`, the harmonic map,
minimising the Dirichlet energy `1/2 sum_c x_c^T L x_c`) some weights are negative on meshes with
obtuse angles summing past pi across an edge, and triangles can flip: `map_distortion(...).flipped`
reports them.

References: W. T. Tutte, "How to draw a graph" (1963); M. S. Floater, "Parametrization and smooth
approximation of surface triangulations" (1997); U. Pinkall, K. Polthier (1993) and M. Eck et al.,
"Multiresolution analysis of arbitrary meshes" (1995) for the harmonic map.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import kernel
from .._indexing import take_rows_or_zero
from .._options import check_solver, check_weights
from .._results import RESULTS, Solution, first_failure, outcome
from ..laplacian import cotan_laplacian
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh
from ..solve import Factorization, factorize
from ..sparse import DirichletPlan, SparseMatrix, dirichlet_blocks, dirichlet_plan
from ._disk import (
    DiskTopology,
    boundary_edge_lengths,
    cached_plan,
    on_device,
    place_boundary,
    require_disk,
    shape_argument,
)


def tutte_embedding(
    mesh: Mesh, *, weights: str = "uniform", shape="circle", solver: str = "auto", throw: bool = True
) -> Float[Array, "nv 2"] | Solution:
    r"""Tutte's barycentric embedding of a disk-topology mesh into the plane (module docstring), `(nv, 2)`.

    $$\sum_{j \sim i} w_{ij} (x_i - x_j) = 0 \quad \text{at every interior vertex } i, \qquad x_b \text{ given on the boundary}$$

    Args:
        mesh: a topological disk (else `DDGInputError`, `ddgjax.param._disk`).
        weights: `"uniform"` (default; `w_ij = 1`, Tutte 1963: no flipped triangles on a convex
            boundary) or `"cotan"` (`w_ij = (cot a_ij + cot b_ij) / 2`: the harmonic map, can flip).
        shape: the boundary's target: `"circle"` (default: the unit circle), `"square"`
            (`[-1, 1]^2`), both with the boundary vertices spaced by arc length of the surface's
            boundary; or `(nb, 2)` positions in the order of `mesh.topology.boundary_loops[0]`
            (counterclockwise for an orientation-preserving map; a convex polygon for the no-flip
            guarantee).
        solver: the `ddgjax.solve.linear_solve` backend (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when the solve fails (default), or return a `ddgjax.Solution` (`stats`: the
            solve's `"residual"` and `"num_steps"`).

    Returns:
        `(nv, 2)` positions; unreferenced vertices at the origin (in a `ddgjax.Solution` with
        `throw=False`). Differentiable in the vertex positions (through the arc-length placement and,
        for cotan weights, the matrix) and in `shape` positions, under `jit`, `grad` and `vmap`.

    libigl: `igl.harmonic(V, F, b, igl.map_vertices_to_circle(V, b), 1)` is the cotan version with
    the circle (libigl's `harmonic` uses `cotmatrix`); gpytoolbox: `tutte_embedding`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> disk = ddgjax.mesh.disk(4)
        >>> cap = disk.with_vertices(disk.vertices.at[:, 2].set(1.0 - jnp.sum(disk.vertices[:, :2] ** 2, axis=1)))
        >>> uv = ddgjax.param.tutte_embedding(cap)
        >>> loop = cap.topology.boundary_loops[0]
        >>> bool(jnp.allclose(jnp.linalg.norm(uv[loop], axis=1), 1.0)), int(ddgjax.param.map_distortion(cap, uv).flipped.sum())
        (True, 0)
    """
    check_weights(weights)
    check_solver(solver)
    disk = require_disk(mesh, "tutte_embedding")
    kind, positions = shape_argument(shape, disk)
    if weights == "cotan":
        matrix = cotan_laplacian(mesh)
    else:  # connectivity only: made once per connectivity and dtype
        matrix = cached_plan(disk, ("uniform", jnp.dtype(mesh.vertices.dtype).name), lambda: uniform_laplacian(mesh))
    uv, result, stats = _embed(
        mesh, matrix, boundary_plan(mesh, disk), on_device(disk, "loop"), positions, kind=kind, solver=solver
    )
    return outcome(uv, result, throw, stats)


def harmonic_map(mesh: Mesh, *, shape="circle", solver: str = "auto", throw: bool = True) -> Float[Array, "nv 2"] | Solution:
    r"""The harmonic map of a disk with a fixed boundary: `tutte_embedding(mesh, weights="cotan", ...)`, `(nv, 2)`.

    Minimises the Dirichlet energy

    $$E_D(u, v) = \tfrac12 (u^\top L u + v^\top L v)$$

    (`L` the PSD cotan Laplacian) with the
    boundary loop on `shape` (`"circle"` by default, arc-length spacing; see `tutte_embedding`, whose
    `solver` and `throw` it takes too). Can flip triangles on meshes with obtuse angles
    (`map_distortion`). libigl: `igl.harmonic(V, F, bnd, igl.map_vertices_to_circle(V, bnd), 1)`.

    Args:
        mesh: a topological disk (else `DDGInputError`).
        shape: the boundary's target, as `tutte_embedding`'s: `"circle"` (default), `"square"` or `(nb, 2)`
            positions in the order of `mesh.topology.boundary_loops[0]`.
        solver: the `ddgjax.solve.linear_solve` backend (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when the solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(nv, 2)` positions, unreferenced vertices at the origin (in a `ddgjax.Solution` with `throw=False`).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> disk = ddgjax.mesh.disk(4)  # a flat unit disk: the map is the identity
        >>> uv = ddgjax.param.harmonic_map(disk)
        >>> uv.shape, bool(jnp.allclose(uv, disk.vertices[:, :2]))
        ((61, 2), True)
    """
    check_solver(solver)
    disk = require_disk(mesh, "harmonic_map")
    kind, positions = shape_argument(shape, disk)
    uv, result, stats = _embed(
        mesh, cotan_laplacian(mesh), boundary_plan(mesh, disk), on_device(disk, "loop"), positions, kind=kind, solver=solver
    )
    return outcome(uv, result, throw, stats)


# One program per mesh size; the Laplacian (a kernel of its own) and the plans are made outside.
@kernel(static_argnames=("kind", "solver"))
def _embed(mesh, matrix, plan, loop, positions, *, kind, solver):
    lengths = boundary_edge_lengths(mesh.vertices, loop)
    fixed = place_boundary(kind, lengths) if positions is None else positions.astype(lengths.dtype)
    factor = factorize(dirichlet_blocks(matrix, plan)[0], solver=solver) if plan is not None else None
    uv, solution = harmonic_extension(matrix, plan, factor, loop, fixed)
    return uv, *solves_outcome(solution)


def uniform_laplacian(mesh: Mesh) -> SparseMatrix:
    """The graph Laplacian `(A x)_i = sum_{j ~ i} (x_i - x_j)` on the vertex pattern, in the vertices' dtype."""
    plan = vertex_plan(mesh)
    n, ne = mesh.n_vertices, mesh.n_edges
    dtype = mesh.vertices.dtype
    entries = jnp.concatenate([jnp.zeros(n, dtype), -jnp.ones(2 * ne, dtype)])
    off_diagonal = take_rows_or_zero(entries, plan.source)
    degrees = -SparseMatrix(off_diagonal, plan.pattern).row_sums()
    # The vertex pattern stores the diagonal first (slots 0..nv-1).
    values = off_diagonal.at[:n].set(degrees)
    return SparseMatrix(values, plan.pattern, symmetric=True, positive_semidefinite=True)


def boundary_plan(mesh: Mesh, disk: DiskTopology) -> DirichletPlan | None:
    """Dirichlet plan of the vertex pattern fixing `[loop | unreferenced]`; `None` when no vertex is free."""
    fixed = np.concatenate([disk.loop, disk.unreferenced])
    if fixed.size == disk.n_vertices:
        return None
    return cached_plan(disk, "boundary", lambda: dirichlet_plan(vertex_plan(mesh).pattern, fixed))


def harmonic_extension(
    matrix: SparseMatrix,
    plan: DirichletPlan | None,
    factor: Factorization | None,
    loop,
    boundary_values: Float[Array, "nb k"],
):
    """`(x, solution)`: `A_ff x_f = -A_fc b` with `x = b` on the loop and 0 at unreferenced vertices.

    `plan` from `boundary_plan`, `factor` a factorisation of its free-free block of `matrix` (reused
    by callers that solve with it more than once); `None` for both when no vertex is free, and then
    `solution` is `None` (nothing solved); else the `LinearSolution` (not raising: callers report it).
    """
    n = matrix.shape[0]
    if plan is None:
        zeros = jnp.zeros((n,) + boundary_values.shape[1:], boundary_values.dtype)
        return zeros.at[loop].set(boundary_values), None
    n_unreferenced = plan.fixed.shape[0] - boundary_values.shape[0]
    fixed = jnp.concatenate([boundary_values, jnp.zeros((n_unreferenced,) + boundary_values.shape[1:], boundary_values.dtype)])
    free_fixed = dirichlet_blocks(matrix, plan)[1]
    solution = factor.solve(-(free_fixed @ fixed), throw=False)
    return plan.join(solution.value.astype(fixed.dtype), fixed), solution


def solves_outcome(*solutions) -> tuple[RESULTS, dict]:
    """`(result, stats)` of the solves that ran (`None`: one that was not needed): the first failing
    outcome, and the largest relative residual and the total CG iterations."""
    ran = [solution for solution in solutions if solution is not None]
    if not ran:
        return RESULTS.successful, {"residual": jnp.zeros(()), "num_steps": jnp.zeros((), jnp.int32)}
    stats = {
        "residual": jnp.max(jnp.stack([solution.residual for solution in ran])),
        "num_steps": sum(solution.num_steps for solution in ran),
    }
    return first_failure(*(solution.result for solution in ran)), stats
