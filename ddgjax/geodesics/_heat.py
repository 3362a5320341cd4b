"""Geodesic distance by the heat method (Crane, Weischedel & Wardetzky 2013), differentiable.

Three steps on a triangle mesh, with `L` the PSD cotan Laplacian and `M` a mass matrix:

1. heat flow for a short time `t = t_coef * h^2` (`h` the mean edge length), one backward-Euler
   step from the sources: `(M + t L) u = delta` (`delta` the sources' hat-function weights: 1 at a
   source vertex, the barycentric coordinates of a source point inside a face);
2. the normalised negative gradient per face, `X = -grad u / |grad u|`, the direction of growing
   distance (0 where `grad u` vanishes, so nothing divides by zero);
3. the Poisson problem `L phi = -div X` (`div` the integrated divergence, `ddgjax.dec.divergence`:
   the weak form holds the natural Neumann condition, and `div X` sums to zero on each connected
   component, so the system is compatible), solved with one vertex pinned per component, then
   shifted so the sources are at 0 (the mean of `phi` over the source points).

On a mesh with boundary, step 1 takes the average of the Neumann solution and the Dirichlet one
(`u = 0` on the boundary), as the paper recommends against distances that bend towards the boundary
(`boundary="average"`, default; `"neumann"` for the plain solve). The result approximates the
geodesic distance to first order in `h` (the smoothing by `t ~ h^2` is part of the method).

`HeatDistanceSolver` keeps the factorisations of `M + t L` (and of its Dirichlet block) and of the
pinned `L`, so each query is three sparse solves and two sweeps over the faces;
`heat_distance(mesh, sources)` builds one and queries it, differentiably in the vertex positions
(every step is a JAX function of them and the solves differentiate implicitly).

References: K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat: a new approach to computing
distance based on heat flow", ACM TOG 32(5) (2013), and "The heat method for distance computation",
CACM 60(11) (2017). potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef).compute_distance(v)`;
libigl: `igl.heat_geodesics_precompute` / `igl.heat_geodesics_solve`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._numerics import safe_norm
from ..dec import divergence, gradient
from ..internal import DirichletData
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, edge_lengths, require_mesh
from ..solve import Factorization, factorize
from ..sparse import DirichletPlan, dirichlet_blocks, dirichlet_plan

BOUNDARY_CONDITIONS = ("average", "neumann")


class HeatMethodSteps(eqx.Module):
    """The heat method's intermediate quantities (module docstring), from `HeatDistanceSolver.steps`.

    Attributes:
        heat: `(nv,)` `u`, the heat after time `t`.
        field: `(nf, 3)` `X = -grad u / |grad u|` per face.
        divergence: `(nv,)` the integrated divergence of `X` (`ddgjax.dec.divergence`; the DDG
            exercises' `div` is its negative).
        distance: `(nv,)` `phi`, shifted to 0 at the sources.
    """

    heat: Float[Array, " nv"]
    field: Float[Array, "nf 3"]
    divergence: Float[Array, " nv"]
    distance: Float[Array, " nv"]


class HeatDistanceSolver(eqx.Module):
    """The heat method's kept factorisations for one mesh: `solver.distance(sources)` per query (module docstring).

    Made by `heat_distance_solver(mesh, ...)`; a pytree, so it passes into `jit` (and its queries
    `vmap` over sources of one shape).

    Attributes:
        mesh: the mesh.
        t: the heat flow's time `t_coef * h^2`.
        heat: factorisation of `M + t L`.
        heat_dirichlet: factorisation of its free-free block with the boundary held at 0
            (`boundary="average"` on a mesh with boundary), else `None`.
        heat_plan: the boundary's `DirichletPlan` for it, else `None`.
        poisson: factorisation of `L` with one vertex per component pinned (its free-free block).
        poisson_plan: the pins' `DirichletPlan`.
        n_pinned: the number of pinned vertices (static).
    """

    mesh: Mesh
    t: Float[Array, ""]
    heat: Factorization
    heat_dirichlet: Factorization | None
    heat_plan: DirichletPlan | None
    poisson: Factorization
    poisson_plan: DirichletPlan
    n_pinned: int = eqx.field(static=True)

    def distance(self, sources) -> Float[Array, " nv"]:
        """Geodesic distance from the sources to every vertex, `(nv,)`, 0 at the sources.

        Args:
            sources: vertex indices, `(m,)` integers (or one integer); or points inside faces, a pair
                `(faces (m,), barycentric (m, 3))` (the barycentric coordinates of each point in its
                face, in the face's vertex order, summing to 1).
        """
        return self.steps(sources).distance

    def steps(self, sources) -> HeatMethodSteps:
        """The distance and the intermediate quantities that lead to it (`HeatMethodSteps`); `sources` as in `distance`."""
        return _steps(self, *_sources(self.mesh, sources))

    def _steps(self, corners, weights) -> HeatMethodSteps:
        mesh = self.mesh
        delta = jnp.zeros(mesh.n_vertices, weights.dtype).at[corners.ravel()].add(weights.ravel())
        u = self.heat.solve(delta).value
        if self.heat_dirichlet is not None:
            plan = self.heat_plan
            u_free = self.heat_dirichlet.solve(delta[plan.free]).value
            u = 0.5 * (u + plan.join(u_free, jnp.zeros(plan.fixed.shape[0], u.dtype)))
        g = gradient(mesh, u)
        norm = safe_norm(g, keepdims=True)
        field = jnp.where(norm > 0, -g / jnp.where(norm > 0, norm, 1.0), 0.0)
        div = divergence(mesh, field)
        plan = self.poisson_plan
        phi = plan.join(self.poisson.solve(-div[plan.free]).value, jnp.zeros(self.n_pinned, div.dtype))
        at_sources = jnp.mean(jnp.sum(phi[corners] * weights, axis=1))
        return HeatMethodSteps(heat=u, field=field, divergence=div, distance=phi - at_sources)


def heat_distance_solver(
    mesh: Mesh,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    method: str = "auto",
) -> HeatDistanceSolver:
    """Factor the heat method's systems for `mesh` once (module docstring); query with `.distance(sources)`.

    Args:
        mesh: a triangle mesh (several components, boundaries, any genus).
        t_coef: the heat flow's time in units of the squared mean edge length (1 in the paper).
        mass: the mass matrix `M`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        boundary: `"average"` (default: the mean of the Neumann and Dirichlet heat flows on a mesh with
            boundary) or `"neumann"`.
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` inside `jit`; `ddgjax.laplacian.laplacian_and_mass`): accurate on
            meshes with obtuse triangles, as potpourri3d's default `use_robust=True`.
        method: the `ddgjax.solve.factorize` backend.

    potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0)`.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("boundary", boundary, BOUNDARY_CONDITIONS)
    if isinstance(t_coef, bool) or not isinstance(t_coef, (int, float, np.integer, np.floating)) or not t_coef > 0:
        raise DDGInputError(f"t_coef: expected a positive number, got {t_coef!r}")
    L, M = laplacian_and_mass(mesh, mass=mass, robust=robust)
    t = t_coef * jnp.mean(edge_lengths(mesh)) ** 2
    heat_matrix = M + t * L
    heat_dirichlet, heat_plan = None, None
    boundary_vertices = mesh.topology.boundary_vertices
    if boundary == "average" and boundary_vertices.size:
        heat_plan = dirichlet_plan(heat_matrix, boundary_vertices)
        heat_dirichlet = factorize(dirichlet_blocks(heat_matrix, heat_plan)[0], method=method)
    pins = DirichletData(mesh, None, None, ())  # one pinned vertex per component (and unreferenced vertices)
    # (flips keep the vertices and the components, so the mesh's pins serve the intrinsic triangulation too)
    poisson_plan = dirichlet_plan(L, pins.fixed)
    return HeatDistanceSolver(
        mesh=mesh,
        t=t,
        heat=factorize(heat_matrix, method=method),
        heat_dirichlet=heat_dirichlet,
        heat_plan=heat_plan,
        poisson=factorize(dirichlet_blocks(L, poisson_plan)[0], method=method),
        poisson_plan=poisson_plan,
        n_pinned=pins.n_pinned,
    )


def heat_distance(
    mesh: Mesh,
    sources,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    method: str = "auto",
) -> Float[Array, " nv"]:
    """Geodesic distance from `sources` by the heat method (module docstring), differentiable in the vertex positions.

    `heat_distance_solver(mesh, ...).distance(sources)`; keep the solver for many queries on one mesh.
    potpourri3d: `compute_distance(V, F, v_ind)`; libigl: `igl.heat_geodesic(V, F, t, gamma)`.
    """
    mesh = require_mesh("mesh", mesh)
    corners, weights = _sources(mesh, sources)
    if robust is not False:
        # The intrinsic triangulation's plans are host data the build looks up: built and kept outside a
        # compiled program (the query itself is compiled).
        solver = heat_distance_solver(mesh, t_coef=t_coef, mass=mass, boundary=boundary, robust=robust, method=method)
        return _steps(solver, corners, weights).distance
    return _build_and_query(mesh, corners, weights, t_coef=t_coef, mass=mass, boundary=boundary, method=method)


# One compiled program per connectivity and source count (an eager call would dispatch and compile
# each operation of the three steps separately).
@kernel(static_argnames=("t_coef", "mass", "boundary", "method"))
def _build_and_query(mesh, corners, weights, *, t_coef, mass, boundary, method) -> Float[Array, " nv"]:
    solver = heat_distance_solver(mesh, t_coef=t_coef, mass=mass, boundary=boundary, method=method)
    return solver._steps(corners, weights).distance


@eqx.filter_jit
def _steps(solver: HeatDistanceSolver, corners, weights) -> HeatMethodSteps:
    return solver._steps(corners, weights)


def _sources(mesh: Mesh, sources) -> tuple[np.ndarray, Float[Array, "m 3"]]:
    """`(corners (m, 3), weights (m, 3))`: each source point as hat-function weights on a face's corners
    (a source vertex `v` is the corners `(v, v, v)` with weights `(1, 0, 0)`)."""
    n = mesh.n_vertices
    if isinstance(sources, tuple):
        if len(sources) != 2:
            raise DDGInputError("sources: a pair (faces (m,), barycentric (m, 3)) for points inside faces")
        faces, weights = np.asarray(sources[0]), jnp.asarray(sources[1])
        if faces.ndim != 1 or not np.issubdtype(faces.dtype, np.integer) or faces.size == 0:
            raise DDGInputError(f"sources: expected a non-empty 1-d integer array of face indices, got {faces!r}")
        if faces.min() < 0 or faces.max() >= mesh.n_faces:
            raise DDGInputError(f"sources: face indices must lie in [0, {mesh.n_faces})")
        if weights.shape != (faces.size, 3):
            raise DDGInputError(f"sources: expected barycentric coordinates of shape ({faces.size}, 3), got {weights.shape}")
        return np.asarray(mesh.topology.faces)[faces], weights.astype(mesh.vertices.dtype)
    vertices = np.atleast_1d(np.asarray(sources))
    if vertices.ndim != 1 or vertices.size == 0 or not np.issubdtype(vertices.dtype, np.integer):
        raise DDGInputError(
            f"sources: expected vertex indices (a non-empty 1-d integer array) or (faces, barycentric), got {sources!r}"
        )
    if vertices.min() < 0 or vertices.max() >= n:
        raise DDGInputError(f"sources: vertex indices must lie in [0, {n}), got {vertices[(vertices < 0) | (vertices >= n)][:5]}")
    weights = jnp.zeros((vertices.size, 3), mesh.vertices.dtype).at[:, 0].set(1.0)
    return np.repeat(vertices[:, None], 3, axis=1), weights
