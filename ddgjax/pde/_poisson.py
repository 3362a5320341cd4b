"""The Poisson problem and harmonic interpolation on a triangle mesh, solved exactly and differentiably.

Sign convention (the reading report, `ddgjax.pde._energies`): the Poisson problem is
`Delta phi = rho` with the pointwise Laplace-Beltrami operator `Delta = -M^{-1} L`, so the discrete
system is

    L phi = -M rho,

the minimiser of `poisson_energy(mesh, phi, rho) = 1/2 phi^T L phi + phi^T M rho`. (The solution of
`-Delta u = f`, e.g. `(1 - r^2) / 4` for `f = 1` on the unit disk, is `solve_poisson(mesh, -f)`.)

Boundary conditions: Dirichlet values on any vertex set (`dirichlet_vertices`), natural Neumann
(zero normal derivative) everywhere else. A connected component without Dirichlet vertices (a
closed surface, or a free piece) determines `phi` only up to a constant and needs `int rho = 0`:
there `rho` is made compatible by removing its area-weighted mean (`rho - int rho / area`), and the
solution is the one with `int phi = 0` on that component. This is exact, not a regularisation: one
vertex per such component is pinned to 0, the remaining positive definite system is solved, and
the constant is fixed afterwards. Unreferenced vertices (empty rows) are set to 0.

`robust=True` (or an `IntrinsicTriangulation`) solves with the intrinsic Delaunay Laplacian and
lumped mass (`ddgjax.laplacian.laplacian_and_mass`): non-negative interior weights, so a harmonic
interpolant obeys the maximum principle on meshes with obtuse triangles too.

The solve goes through `ddgjax.solve.linear_solve` on the free-free block of `L`
(`ddgjax.sparse.dirichlet_blocks`), so `phi` is differentiable with respect to `rho`, the Dirichlet
values and the vertex positions (reverse mode), under `jit` and `vmap`.

References: the reading report, "The Poisson problem" (Crane's DDG notes, ch. 6); libigl
`min_quad_with_fixed` and `harmonic`; gpytoolbox `min_quad_with_fixed`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_choice
from .._results import RESULTS, raise_if_failed
from ..internal import resolve_robust, vertex_plan
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, require_mesh
from ..solve import linear_solve
from ..sparse import dirichlet_blocks, dirichlet_plan

MASSES = ("voronoi", "barycentric", "galerkin")


def solve_poisson(
    mesh: Mesh,
    rho: Float[ArrayLike, "nv *k"],
    *,
    dirichlet_vertices: Int[ArrayLike, " n_fixed"] | None = None,
    dirichlet_values: Float[ArrayLike, " n_fixed *k"] | None = None,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    method: str = "auto",
) -> Float[Array, "nv *k"]:
    """Solve the Poisson problem `Delta phi = rho`, i.e. `L phi = -M rho` (module docstring).

    Args:
        mesh: any triangle mesh (closed, with boundary, several components).
        rho: `(nv,)` or `(nv, k)` pointwise right-hand side at the vertices.
        dirichlet_vertices: `(n_fixed,)` distinct vertex indices whose values are prescribed (concrete,
            host data). Default: none (Neumann everywhere).
        dirichlet_values: `(n_fixed,)` or `(n_fixed, k)` values there (default 0).
        mass: the mass matrix `M`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` from `intrinsic_delaunay(mesh)` inside `jit` / `grad`).
        method: the backend of `linear_solve` (`"auto"`, `"cholesky"`, `"superlu"`, `"cg"`, `"pyamg"`).

    Returns:
        `phi`, the shape of `rho`. A failed solve raises through `ddgjax.RESULTS` (use
        `linear_solve(..., throw=False)` on the blocks to inspect one).

    libigl: `igl.min_quad_with_fixed(L, M @ rho, known, values, ...)` with `L = -igl.cotmatrix`.
    """
    phi, result = poisson_with_result(
        mesh,
        rho,
        dirichlet_vertices=dirichlet_vertices,
        dirichlet_values=dirichlet_values,
        mass=mass,
        robust=robust,
        method=method,
    )
    return raise_if_failed(phi, result, throw=True)


def poisson_with_result(
    mesh, rho, *, dirichlet_vertices=None, dirichlet_values=None, mass="voronoi", robust=False, method="auto"
):
    """`solve_poisson`'s `(phi, result)` (`ddgjax.RESULTS`), raising nothing: for callers that check the
    outcome themselves (a program without the run-time check, which JAX's persistent cache keeps)."""
    mesh = require_mesh("mesh", mesh)
    check_choice("mass", mass, MASSES)
    triangulation = resolve_robust(mesh, robust, mass=mass)
    rho = _vertex_values("rho", mesh, rho)
    pattern = (vertex_plan(mesh) if triangulation is None else triangulation.plan.vertex_plan).pattern
    dirichlet = DirichletData(mesh, dirichlet_vertices, dirichlet_values, rho.shape[1:], pattern)
    if dirichlet.plan is None:  # every vertex prescribed: nothing to solve
        phi = jnp.zeros_like(rho).at[dirichlet.vertices].set(dirichlet.values.astype(rho.dtype))
        return phi, RESULTS.successful
    fixed_values = dirichlet.fixed_values(rho.dtype)
    floating = dirichlet.floating[dirichlet.labels]  # vertices whose component has no Dirichlet vertex
    return _solve(
        mesh, triangulation, rho, fixed_values, dirichlet.plan, dirichlet.labels, floating, dirichlet.n_components, mass, method
    )


# One compiled program per connectivity and size (the mesh's topology is static): an eager call does
# not dispatch (and compile) each operation separately. The outcome is checked outside it, so the
# program has no host callback and JAX's persistent compilation cache can keep it.
@functools.partial(jax.jit, static_argnums=(7, 8, 9))
def _solve(mesh, triangulation, rho, fixed_values, plan, labels, floating, n_components, mass, method):
    robust = False if triangulation is None else triangulation
    laplacian, mass_matrix_ = laplacian_and_mass(mesh, mass=mass, robust=robust)
    areas = mass_matrix_.row_sums()  # M 1: the area of each vertex (Galerkin rows sum to it too)
    component_area = jax.ops.segment_sum(areas, labels, n_components)

    def component_mean(values):
        """`int values / area` of each vertex's component, `(nv, ...)`."""
        integral = jax.ops.segment_sum(mass_matrix_ @ values, labels, n_components)
        return (integral / _broadcast(component_area, integral))[labels]

    compatible = rho - jnp.where(_broadcast(floating, rho), component_mean(rho), 0.0)
    rhs = -(mass_matrix_ @ compatible)
    free_free, free_fixed = dirichlet_blocks(laplacian, plan)
    solution = linear_solve(free_free, rhs[plan.free] - free_fixed @ fixed_values, method=method, throw=False)
    phi = plan.join(solution.value, fixed_values)
    return phi - jnp.where(_broadcast(floating, phi), component_mean(phi), 0.0), solution.result


def harmonic_interpolation(
    mesh: Mesh,
    vertices: Int[ArrayLike, " n_fixed"],
    values: Float[ArrayLike, " n_fixed *k"],
    *,
    robust: bool | IntrinsicTriangulation = False,
    method: str = "auto",
) -> Float[Array, "nv *k"]:
    """The report's smoothest interpolant: `L phi = 0` away from `vertices`, `phi = values` on them.

    The minimiser of the Dirichlet energy `1/2 int |grad phi|^2` with the given values (natural
    Neumann boundary elsewhere). A component without a constrained vertex gets 0 (its harmonic
    functions are the constants; the zero-mean one). Differentiable in `values` and the vertex
    positions. libigl: `igl.harmonic(V, F, vertices, values, 1)`; gpytoolbox: `min_quad_with_fixed`
    with `L` and no linear term.

    Args:
        mesh: any triangle mesh.
        vertices: `(n_fixed,)` distinct vertex indices, at least one.
        values: `(n_fixed,)` or `(n_fixed, k)` values at them (e.g. `(n_fixed, 3)` positions).
        robust: the intrinsic Delaunay Laplacian (`solve_poisson`): with it the interpolant lies
            between the smallest and largest values (the maximum principle) on any mesh.
        method: the backend of `linear_solve`.
    """
    mesh = require_mesh("mesh", mesh)
    if vertices is None or np.size(vertices) == 0:
        raise DDGInputError("vertices: expected at least one vertex to interpolate from, got none")
    values = jnp.asarray(values)
    if values.ndim not in (1, 2):
        raise DDGInputError(f"values: expected shape (n_fixed,) or (n_fixed, k), got {values.shape}")
    rho = jnp.zeros((mesh.n_vertices,) + values.shape[1:], values.dtype if jnp.issubdtype(values.dtype, jnp.floating) else float)
    return solve_poisson(mesh, rho, dirichlet_vertices=vertices, dirichlet_values=values, robust=robust, method=method)


class DirichletData:
    """Host bookkeeping of a Poisson problem: components, pinned vertices, the block plan."""

    def __init__(self, mesh: Mesh, vertices, values, trailing: tuple[int, ...], pattern=None):
        """`pattern`: the Laplacian's sparsity pattern the plan is of (default: the mesh's own)."""
        topology = mesh.topology
        n = mesh.n_vertices
        if vertices is None:
            if values is not None:
                raise DDGInputError("dirichlet_values: given without dirichlet_vertices; pass both or neither")
            vertices = np.zeros(0, dtype=np.int64)
        vertices = np.asarray(vertices)
        if vertices.ndim != 1 or not (np.issubdtype(vertices.dtype, np.integer) or vertices.size == 0):
            raise DDGInputError(
                f"dirichlet_vertices: expected a 1-d integer array of vertex indices, got shape {vertices.shape} dtype {vertices.dtype}"
            )
        vertices = vertices.astype(np.int64)
        outside = (vertices < 0) | (vertices >= n)
        if outside.any():
            raise DDGInputError(f"dirichlet_vertices: vertex indices must lie in [0, {n}), got {vertices[outside][:5].tolist()}")
        if np.unique(vertices).size != vertices.size:
            raise DDGInputError("dirichlet_vertices: expected distinct vertices, got repeated ones")
        if values is None:
            values = jnp.zeros((vertices.size,) + trailing)
        values = jnp.asarray(values)
        if values.shape != (vertices.size,) + trailing:
            raise DDGInputError(
                f"dirichlet_values: expected shape {(vertices.size,) + trailing} (one value per Dirichlet vertex, "
                f"as many columns as rho), got {values.shape}"
            )
        # Component of each vertex (unreferenced vertices: their own label, past the face components).
        labels = np.full(n, topology.n_components, dtype=np.int32)
        labels[topology.faces.ravel()] = np.repeat(topology.face_components, 3)
        unreferenced = topology.unreferenced_vertices
        constrained = np.zeros(topology.n_components + 1, dtype=bool)
        constrained[labels[vertices]] = True
        floating = ~constrained
        floating[-1] = False  # unreferenced vertices are fixed to 0, not re-centred
        # Pin the lowest vertex of each floating component (components are numbered by first face).
        first_vertex = np.full(topology.n_components, n, dtype=np.int64)
        np.minimum.at(first_vertex, labels[labels < topology.n_components], np.flatnonzero(labels < topology.n_components))
        pins = first_vertex[floating[:-1]]
        extra = np.setdiff1d(unreferenced, vertices)
        fixed = np.concatenate([vertices, pins, extra])
        self.fixed = fixed  # host copy: the plan's arrays are traced when this runs inside jit
        if pattern is None:
            pattern = vertex_plan(mesh).pattern
        self.plan = dirichlet_plan(pattern, fixed) if fixed.size < n else None
        self.vertices = vertices
        self.values = values
        self.n_pinned = pins.size + extra.size
        self.labels = jnp.asarray(labels)
        self.n_components = topology.n_components + 1
        self.floating = jnp.asarray(floating)

    def fixed_values(self, dtype) -> Float[Array, " n_fixed *k"]:
        zeros = jnp.zeros((self.n_pinned,) + self.values.shape[1:], dtype)
        return jnp.concatenate([self.values.astype(dtype), zeros])


def _vertex_values(name: str, mesh: Mesh, values) -> Float[Array, "nv *k"]:
    n = mesh.n_vertices
    if np.ndim(values) not in (1, 2) or np.shape(values)[0] != n:
        raise DDGInputError(f"{name}: expected shape ({n},) or ({n}, k), got {np.shape(values)}")
    values = jnp.asarray(values)
    return values if jnp.issubdtype(values.dtype, jnp.floating) else values.astype(float)


def _broadcast(x, like):
    return x.reshape(x.shape + (1,) * (like.ndim - x.ndim))
