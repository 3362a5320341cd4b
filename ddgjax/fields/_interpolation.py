"""Tangent fields interpolated from a few vertices with the connection Laplacian (a Dirichlet problem).

    minimise u^H A u  subject to  u_c = fixed_values,   i.e.   A_ff u_f = -A_fc u_c,

the discrete harmonic extension in the connection (Knoeppel et al. 2013, section 6.1: fixed
directions as hard constraints). The free-free block is Hermitian positive definite when every
component of the mesh holds a constrained vertex and the connection Laplacian is (e.g. Delaunay
meshes); it is solved once with `ddgjax.solve.linear_solve`, differentiable in the values and the
vertex positions by implicit differentiation.
"""

from __future__ import annotations

import weakref

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float, Inexact, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_vertex_indices
from .._options import check_solver
from .._results import RESULTS, Solution, outcome
from ..laplacian import TriangulationPlan
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, MeshTopology, require_mesh
from ..solve import linear_solve
from ..sparse import DirichletPlan, SparseMatrix, SparsityPattern, dirichlet_blocks, dirichlet_plan
from ._connection import check_boundary_scaling, plan_of
from ._laplacian import check_degree, planned_connection_laplacian
from ._plan import FieldPlan


def interpolate_field(
    mesh: Mesh,
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"],
    fixed_values: Inexact[ArrayLike, " n_fixed"],
    n: int = 1,
    boundary_scaling: str = "geodesic",
    solver: str = "auto",
    throw: bool = True,
) -> Complex[Array, " nv"] | Solution:
    """The smoothest `n`-direction field taking the given values at the given vertices, `(nv,)` complex.

    Minimises `u^H A u` (`A = connection_laplacian(mesh, n=n, boundary_scaling=boundary_scaling)`) with
    `u = fixed_values` at `fixed_vertices` (module docstring). Values are `n`-th powers in the
    vertices' polar coordinates (`ddgjax.fields._connection`; a 3D tangent vector `v` at vertex `i`
    is `(v . e1 + i v . e2)^n` with `(e1, e2)` from `tangent_bases`); magnitudes are interpolated
    too (normalise the result, `u / |u|`, for directions). On a flat region with
    `boundary_scaling="unscaled"` a single constraint gives the constant field. Differentiable in
    `fixed_values` and the vertex positions.

    Args:
        mesh: the mesh (manifold, consistently oriented).
        fixed_vertices: `(n_fixed,)` distinct vertex indices, at least one per connected component
            (keyword-only, as every function's constrained vertices).
        fixed_values: `(n_fixed,)` complex values at them.
        n: number of directions.
        boundary_scaling: `"geodesic"` (default) or `"unscaled"`.
        solver: the `linear_solve` backend (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when the solve fails (default), or return a `ddgjax.Solution` (`stats`: the
            solve's `"residual"` and `"num_steps"`).

    Returns:
        `(nv,)` complex field (in a `ddgjax.Solution` with `throw=False`).

    Reference: Knoeppel et al. 2013, section 6.1; N. Sharp, Y. Soliman, K. Crane, "The vector heat
    method" (2019), whose vector diffusion `(M + t A) u = u_0` approaches this as `t` grows
    (potpourri3d `MeshVectorHeatSolver.transport_tangent_vectors` normalises magnitudes separately).
    libigl: `igl.harmonic` is the scalar counterpart.
    """
    mesh = require_mesh("mesh", mesh)
    n = check_degree(n)
    check_boundary_scaling(boundary_scaling)
    check_solver(solver)
    fixed = check_vertex_indices("fixed_vertices", fixed_vertices, mesh.n_vertices, minimum=1)
    if np.shape(fixed_values) != fixed.shape:
        raise DDGInputError(
            f"fixed_values: expected shape {fixed.shape} (one complex number per vertex), got {np.shape(fixed_values)}"
        )
    field_plan, vertex = plan_of(mesh), vertex_plan(mesh)
    values = device_array(fixed_values)
    blocks = _blocks(mesh.topology, vertex.pattern, fixed)
    if blocks.free.shape[0] == 0:
        return outcome(_complex(values)[np.argsort(fixed)], RESULTS.successful, throw)
    u, result, stats = _interpolate(
        mesh, field_plan, vertex, blocks, values, float(n), boundary_scaling=boundary_scaling, solver=solver
    )
    return outcome(u, result, throw, stats)


def _complex(values: Inexact[Array, "..."]) -> Complex[Array, "..."]:
    return values.astype(jnp.result_type(values.dtype, jnp.complex64))


# The block plans of the last few constraint sets per connectivity: interpolating again from the same
# vertices (new values, moved vertices) skips the host work.
_BLOCKS: "weakref.WeakKeyDictionary[MeshTopology, dict]" = weakref.WeakKeyDictionary()
_BLOCKS_KEPT = 8


def _blocks(topology: MeshTopology, pattern: SparsityPattern, fixed: np.ndarray) -> DirichletPlan:
    """`dirichlet_plan(pattern, fixed)`, cached per connectivity and fixed vertices."""
    kept = _BLOCKS.setdefault(topology, {})
    key = fixed.astype(np.int64).tobytes()
    plan = kept.get(key)
    if plan is None:
        with jax.ensure_compile_time_eval():  # host data even when a caller's jit traces this call (it is cached)
            plan = dirichlet_plan(pattern, fixed)
        if len(kept) >= _BLOCKS_KEPT:
            kept.pop(next(iter(kept)))
        kept[key] = plan
    return plan


# The outcome is checked outside the program (`outcome`), as `solve_poisson` does.
@kernel(static_argnames=("boundary_scaling", "solver"))
def _interpolate(
    mesh: Mesh,
    field_plan: FieldPlan,
    vertex: TriangulationPlan,
    plan: DirichletPlan,
    values: Inexact[Array, " n_fixed"],
    n: Float[ArrayLike, ""],
    *,
    boundary_scaling: str,
    solver: str,
) -> tuple[Complex[Array, " nv"], RESULTS, dict[str, Array]]:
    """`(u, result, stats)` of `interpolate_field`; `mesh` comes without its topology, the plans are passed in."""
    values = _complex(values)
    A = planned_connection_laplacian(mesh, field_plan, vertex, n, boundary_scaling=boundary_scaling)
    # The blocks and the join are gathers of the real and imaginary parts (`gather_sum` is typed real).
    real, imaginary = (dirichlet_blocks(SparseMatrix(part, A.pattern), plan) for part in (A.values.real, A.values.imag))
    free_free = SparseMatrix(
        real[0].values + 1j * imaginary[0].values, plan.free_free, hermitian=True, positive_semidefinite=True
    )
    free_fixed = SparseMatrix(real[1].values + 1j * imaginary[1].values, plan.free_fixed)
    solve = linear_solve(free_free, -(free_fixed @ values), solver=solver, throw=False)
    u = jax.lax.complex(plan.join(solve.value.real, values.real), plan.join(solve.value.imag, values.imag))
    return u, solve.result, solve.stats
