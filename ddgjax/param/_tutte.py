"""Fixed-boundary maps of a disk into the plane: Tutte's embedding and the harmonic (cotan) map.

With the boundary loop pinned to positions `b` in the plane, each interior vertex is the weighted
average of its neighbours,

    sum_j w_ij (x_i - x_j) = 0   at interior vertices i,   x = b on the boundary,

i.e. `A_ff x_f = -A_fc b` for the weighted graph Laplacian `A` (`ddgjax.sparse.dirichlet_blocks`),
one sparse solve with two right-hand sides (`ddgjax.solve.linear_solve`, differentiable by implicit
differentiation). With positive weights (`"uniform"`, `w_ij = 1`) and the boundary on a convex polygon
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

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import check_choice
from .._indexing import take_rows_or_zero
from .._options import LINEAR_SOLVERS as METHODS
from .._results import RESULTS, raise_if_failed
from ..internal import vertex_plan
from ..laplacian import cotan_laplacian
from ..mesh import Mesh
from ..solve import Factorization, factorize
from ..sparse import DirichletPlan, SparseMatrix, dirichlet_blocks, dirichlet_plan
from ._disk import DiskTopology, boundary_argument, boundary_edge_lengths, cached_plan, place_boundary, require_disk

WEIGHTS = ("uniform", "cotan")


def tutte_embedding(mesh: Mesh, *, weights: str = "uniform", boundary="circle", method: str = "auto") -> Float[Array, "nv 2"]:
    """Tutte's barycentric embedding of a disk-topology mesh into the plane (module docstring), `(nv, 2)`.

    Args:
        mesh: a topological disk (else `DDGInputError`, `ddgjax.param._disk`).
        weights: `"uniform"` (default; `w_ij = 1`, Tutte 1963: no flipped triangles on a convex
            boundary) or `"cotan"` (`w_ij = (cot a_ij + cot b_ij) / 2`: the harmonic map, can flip).
        boundary: `"circle"` (default: the unit circle), `"square"` (`[-1, 1]^2`), both with the
            boundary vertices spaced by arc length of the surface's boundary; or `(nb, 2)` positions
            in the order of `mesh.topology.boundary_loops[0]` (counterclockwise for an
            orientation-preserving map; a convex polygon for the no-flip guarantee).
        method: the `ddgjax.solve.linear_solve` backend (`"auto"`, `"cholesky"`, `"superlu"`, `"cg"`,
            `"pyamg"`).

    Returns:
        `(nv, 2)` positions; unreferenced vertices at the origin. Differentiable in the vertex
        positions (through the arc-length placement and, for cotan weights, the matrix) and in
        `boundary` positions, under `jit`, `grad` and `vmap`.

    libigl: `igl.harmonic(V, F, b, igl.map_vertices_to_circle(V, b), 1)` is the cotan version with
    the circle (libigl's `harmonic` uses `cotmatrix`); gpytoolbox: `tutte_embedding`.
    """
    check_choice("weights", weights, WEIGHTS)
    check_choice("method", method, METHODS)
    disk = require_disk(mesh, "tutte_embedding")
    kind, positions = boundary_argument(boundary, disk)
    plan = boundary_plan(mesh, disk)
    uv, result = _embed(mesh, plan, jnp.asarray(disk.loop), positions, kind, weights, method)
    return raise_if_failed(uv, result, throw=True)


def harmonic_map(mesh: Mesh, *, boundary="circle", method: str = "auto") -> Float[Array, "nv 2"]:
    """The harmonic map of a disk with a fixed boundary: `tutte_embedding(mesh, weights="cotan", ...)`, `(nv, 2)`.

    Minimises the Dirichlet energy `1/2 (u^T L u + v^T L v)` (`L` the PSD cotan Laplacian) with the
    boundary loop on `boundary` (`"circle"` by default, arc-length spacing; see `tutte_embedding`).
    Can flip triangles on meshes with obtuse angles (`map_distortion`). libigl:
    `igl.harmonic(V, F, bnd, igl.map_vertices_to_circle(V, bnd), 1)`.
    """
    check_choice("method", method, METHODS)
    disk = require_disk(mesh, "harmonic_map")
    kind, positions = boundary_argument(boundary, disk)
    plan = boundary_plan(mesh, disk)
    uv, result = _embed(mesh, plan, jnp.asarray(disk.loop), positions, kind, "cotan", method)
    return raise_if_failed(uv, result, throw=True)


# One program per connectivity (the mesh's topology is static); the outcome is raised outside.
@functools.partial(jax.jit, static_argnums=(4, 5, 6))
def _embed(mesh, plan, loop, positions, kind, weights, method):
    lengths = boundary_edge_lengths(mesh.vertices, loop)
    fixed = place_boundary(kind, lengths) if positions is None else positions.astype(lengths.dtype)
    matrix = cotan_laplacian(mesh) if weights == "cotan" else uniform_laplacian(mesh)
    factor = factorize(dirichlet_blocks(matrix, plan)[0], method=method) if plan is not None else None
    return harmonic_extension(matrix, plan, factor, loop, fixed)


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
) -> tuple[Float[Array, "nv k"], RESULTS]:
    """`(x, result)`: `A_ff x_f = -A_fc b` with `x = b` on the loop and 0 at unreferenced vertices.

    `plan` from `boundary_plan`, `factor` a factorisation of its free-free block of `matrix` (reused
    by callers that solve with it more than once); `None` for both when no vertex is free.
    """
    n = matrix.shape[0]
    if plan is None:
        zeros = jnp.zeros((n,) + boundary_values.shape[1:], boundary_values.dtype)
        return zeros.at[loop].set(boundary_values), RESULTS.successful
    n_unreferenced = plan.fixed.shape[0] - boundary_values.shape[0]
    fixed = jnp.concatenate([boundary_values, jnp.zeros((n_unreferenced,) + boundary_values.shape[1:], boundary_values.dtype)])
    free_fixed = dirichlet_blocks(matrix, plan)[1]
    solution = factor.solve(-(free_fixed @ fixed), throw=False)
    return plan.join(solution.value.astype(fixed.dtype), fixed), solution.result
