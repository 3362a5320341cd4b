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
(`boundary="average"`, default; `"neumann"` or `"dirichlet"` for one of the two). The result approximates the
geodesic distance to first order in `h` (the smoothing by `t ~ h^2` is part of the method).

`HeatDistanceSolver` keeps the factorisations of `M + t L` (and of its Dirichlet block) and of the
pinned `L`, so each query is three sparse solves and two sweeps over the faces;
`heat_distance(mesh, sources)` builds one and queries it, differentiably in the vertex positions
(every step is a JAX function of them and the solves differentiate implicitly), in one compiled
program. Each solve reports its outcome (`ddgjax.RESULTS`); a query's `result` is the first failing
solve's (heat flow, its Dirichlet half, Poisson), and `throw=False` returns a `ddgjax.Solution` whose
`stats` hold the largest relative residual of the solves and their total CG iterations.

References: K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat: a new approach to computing
distance based on heat flow", ACM TOG 32(5) (2013), and "The heat method for distance computation",
CACM 60(11) (2017). potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef).compute_distance(v)`;
libigl: `igl.heat_geodesics_precompute` / `igl.heat_geodesics_solve`.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._numerics import safe_norm
from .._options import BOUNDARY_CONDITIONS, check_mass, check_solver
from .._results import RESULTS, Solution, first_failure, outcome
from ..dec import divergence, gradient
from ..internal import DirichletData, resolve_robust
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, MeshTopology, edge_lengths, require_mesh
from ..solve import Factorization, LinearSolution, factorize
from ..sparse import DirichletPlan, SparseMatrix, SparsityPattern, dirichlet_blocks, dirichlet_plan

HEAT_BOUNDARY_CONDITIONS = ("average", *BOUNDARY_CONDITIONS)
"""`boundary=` of the heat method: `BOUNDARY_CONDITIONS` and their mean, `"average"` (module docstring)."""


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
        heat: factorisation of `M + t L` (`None` with `boundary="dirichlet"` on a mesh with boundary).
        heat_dirichlet: factorisation of its free-free block with the boundary held at 0
            (`boundary="average"` or `"dirichlet"` on a mesh with boundary), else `None`.
        heat_plan: the boundary's `DirichletPlan` for it, else `None`.
        poisson: factorisation of `L` with one vertex per component pinned (its free-free block).
        poisson_plan: the pins' `DirichletPlan`.
    """

    mesh: Mesh
    t: Float[Array, ""]
    heat: Factorization | None
    heat_dirichlet: Factorization | None
    heat_plan: DirichletPlan | None
    poisson: Factorization
    poisson_plan: DirichletPlan

    @property
    def n_pinned(self) -> int:
        """The number of vertices the Poisson solve pins (one per connected component, and unreferenced ones)."""
        return self.poisson_plan.fixed.shape[0]

    def distance(self, sources, *, throw: bool = True) -> Float[Array, " nv"] | Solution:
        """Geodesic distance from the sources to every vertex, `(nv,)`, 0 at the sources.

        Args:
            sources: vertex indices, `(m,)` integers (or one integer); or points inside faces, a pair
                `(faces (m,), barycentric (m, 3))` (the barycentric coordinates of each point in its
                face, in the face's vertex order, summing to 1).
            throw: raise when a solve fails (default), or return a `ddgjax.Solution` (module docstring).
        """
        steps, result, stats = _query(self.mesh, self._factors(), *_sources(self.mesh, sources))
        return outcome(steps.distance, result, throw, stats)

    def steps(self, sources, *, throw: bool = True) -> HeatMethodSteps | Solution:
        """The distance and the intermediate quantities that lead to it (`HeatMethodSteps`); arguments as `distance`."""
        steps, result, stats = _query(self.mesh, self._factors(), *_sources(self.mesh, sources))
        return outcome(steps, result, throw, stats)

    def _factors(self) -> "_Factors":
        return _Factors(self.heat, self.heat_dirichlet, self.heat_plan, self.poisson, self.poisson_plan)


class _Factors(eqx.Module):
    """What a query needs besides the mesh (the solver without its mesh, which a kernel takes apart)."""

    heat: Factorization | None
    heat_dirichlet: Factorization | None
    heat_plan: DirichletPlan | None
    poisson: Factorization
    poisson_plan: DirichletPlan


class _Plans(eqx.Module):
    """The host data of the heat method for one triangulation: the Dirichlet plan of the heat flow's
    boundary (`None` without one, or with Neumann conditions), whether the Neumann heat flow is
    needed, and the Poisson solve's pins."""

    heat: DirichletPlan | None
    poisson: DirichletPlan
    neumann: bool = eqx.field(static=True)


_PLANS: "weakref.WeakKeyDictionary[MeshTopology, dict]" = weakref.WeakKeyDictionary()


def _plans(mesh: Mesh, boundary: str, pattern: SparsityPattern, cached: bool) -> _Plans:
    """`_Plans` on the Laplacian's `pattern`: the mesh's own (`cached` per connectivity) or its intrinsic
    triangulation's (the same vertices and components, so the mesh's pins serve it too)."""
    if not cached:
        return _build_plans(mesh, boundary, pattern)
    cache = _PLANS.setdefault(mesh.topology, {})
    if boundary not in cache:
        cache[boundary] = _build_plans(mesh, boundary, pattern)
    return cache[boundary]


def _build_plans(mesh: Mesh, boundary: str, pattern: SparsityPattern) -> _Plans:
    boundary_vertices = mesh.topology.boundary_vertices
    held = boundary != "neumann" and boundary_vertices.size > 0
    with jax.ensure_compile_time_eval():  # host data even when a caller's jit traces this call (it is cached)
        heat = dirichlet_plan(pattern, boundary_vertices) if held else None
        pins = DirichletData(mesh, None, None, (), pattern)  # one pinned vertex per component (and unreferenced ones)
        poisson = dirichlet_plan(pattern, pins.fixed)
    return _Plans(heat=heat, poisson=poisson, neumann=not (held and boundary == "dirichlet"))


def _operators(mesh: Mesh, t_coef, mass: str, boundary: str, robust, solver: str):
    """Checked options, then `(L, M, plans, t_coef)`: what the kernels below take (host work and plans here)."""
    check_choice("boundary", boundary, HEAT_BOUNDARY_CONDITIONS)
    check_mass(mass)
    check_solver(solver)
    if isinstance(t_coef, bool) or not isinstance(t_coef, (int, float, np.integer, np.floating)) or not t_coef > 0:
        raise DDGInputError(f"t_coef: expected a positive number, got {t_coef!r}")
    triangulation = resolve_robust(mesh, robust, mass=mass)
    L, M = laplacian_and_mass(mesh, mass=mass, robust=False if triangulation is None else triangulation)
    plans = _plans(mesh, boundary, L.pattern, cached=triangulation is None)
    return L, M, plans, jnp.asarray(float(t_coef), L.values.dtype)


def heat_distance_solver(
    mesh: Mesh,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
) -> HeatDistanceSolver:
    """Factor the heat method's systems for `mesh` once (module docstring); query with `.distance(sources)`.

    Args:
        mesh: a triangle mesh (several components, boundaries, any genus).
        t_coef: the heat flow's time in units of the squared mean edge length (1 in the paper).
        mass: the mass matrix `M`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        boundary: the heat flow's boundary condition on a mesh with boundary: `"average"` (default:
            the mean of the Neumann and Dirichlet heat flows), `"neumann"` or `"dirichlet"`.
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` inside `jit`; `ddgjax.laplacian.laplacian_and_mass`): accurate on
            meshes with obtuse triangles, as potpourri3d's default `use_robust=True`.
        solver: the backend of the kept factorisations (`ddgjax.LINEAR_SOLVERS`, `ddgjax.solve.factorize`).

    Returns:
        `HeatDistanceSolver`; its queries take `throw=`.

    potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0)` (defaults compared in `heat_distance`);
    libigl: `igl.heat_geodesics_precompute(V, F, t, data)`.
    """
    mesh = require_mesh("mesh", mesh)
    L, M, plans, t_coef = _operators(mesh, t_coef, mass, boundary, robust, solver)
    t, factors = _factor(mesh, L, M, plans, t_coef, solver=solver)
    return HeatDistanceSolver(
        mesh=mesh,
        t=t,
        heat=factors.heat,
        heat_dirichlet=factors.heat_dirichlet,
        heat_plan=factors.heat_plan,
        poisson=factors.poisson,
        poisson_plan=factors.poisson_plan,
    )


def heat_distance(
    mesh: Mesh,
    sources,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, " nv"] | Solution:
    """Geodesic distance from `sources` to every vertex by the heat method (Crane, Weischedel & Wardetzky 2013), `(nv,)`.

    With `L` the PSD cotan Laplacian, `M` the mass matrix and `h` the mean edge length:

    1. `(M + t L) u = delta`, `t = t_coef * h^2`: one backward-Euler step of the heat flow from the
       sources (`delta`: the sources' hat-function weights);
    2. `X = -grad u / |grad u|` on each face (0 where `grad u = 0`);
    3. `L phi = -div X` (integrated divergence; one vertex pinned per connected component), then
       `phi` shifted so that its mean over the sources is 0.

    Convention: distances are non-negative away from the sources and 0 at them (a source inside a
    face: its interpolated value is 0); first-order accurate in `h` (the smoothing by `t ~ h^2`
    belongs to the method: a larger `t_coef` gives smoother, less accurate distances). With
    `boundary="average"` (default) the heat flow on a mesh with boundary is the mean of its Neumann and
    Dirichlet (`u = 0` on the boundary) solutions, the paper's remedy against distances bent towards
    the boundary; `"neumann"` and `"dirichlet"` use one of them. Several components, boundaries and
    any genus are fine. Differentiable in the vertex positions (every step is a JAX function of them,
    the solves by implicit differentiation), under `jit`, `grad` and `vmap`; an eager call runs one
    compiled program after the Laplacian's. For many queries on one mesh keep the factorisations:
    `heat_distance_solver(mesh, ...).distance(sources)`.

    Args:
        mesh: a triangle mesh.
        sources: vertex indices, `(m,)` integers (or one integer); or points inside faces, a pair
            `(faces (m,), barycentric (m, 3))`.
        t_coef: the heat flow's time in units of `h^2` (default 1, the paper's).
        mass: `M`, one of `ddgjax.MASS_MATRICES` (default `"voronoi"`).
        boundary: `"average"` (default), `"neumann"` or `"dirichlet"` (the heat flow's boundary condition).
        robust: the intrinsic Delaunay Laplacian and lumped mass (`True`, or an
            `IntrinsicTriangulation` inside `jit`): accurate on meshes with obtuse triangles.
        solver: the backend of the three sparse solves, one of `ddgjax.LINEAR_SOLVERS` (default `"auto"`).
        throw: raise when a solve fails (default), or return a `ddgjax.Solution` (`result`: the first
            failing solve's outcome; `stats`: `"residual"`, the largest relative residual of the solves,
            and `"num_steps"`, their CG iterations).

    Returns:
        `(nv,)` distances (in a `ddgjax.Solution` with `throw=False`).

    Equivalents and their defaults: libigl `igl.heat_geodesics_precompute(V, F, data)` /
    `igl.heat_geodesics_solve(data, gamma)` has the same defaults (`t = h^2`, Voronoi mass, the average of
    the Neumann and Dirichlet heat flows, the mean over the sources shifted to 0). potpourri3d
    `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=True).compute_distance(v)` (geometry-central)
    differs in three defaults: it uses the intrinsic Delaunay Laplacian of a mollified tufted cover
    (`use_robust=True`; here `robust=False`, and `robust=True` is the intrinsic Delaunay Laplacian
    without the mollification and the tufted cover), the lumped barycentric mass (here `"voronoi"`:
    pass `mass="barycentric"`), and the Neumann heat flow only (here `"average"` on meshes with boundary:
    pass `boundary="neumann"`); `t_coef` means the same (`t = t_coef h^2`, `h` the mean edge length).
    With `mass="barycentric", boundary="neumann", robust=False` and potpourri3d's `use_robust=False`
    the two agree to a few 1e-4 of the largest distance (a slightly different time or regularisation in
    geometry-central; tests).

    Reference: K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat" (2013), sections 3.1-3.2 and
    (boundary conditions) 3.4; "The heat method for distance computation" (2017).
    """
    mesh = require_mesh("mesh", mesh)
    corners, weights = _sources(mesh, sources)
    L, M, plans, t_coef = _operators(mesh, t_coef, mass, boundary, robust, solver)
    distance, result, stats = _build_and_query(mesh, L, M, plans, t_coef, corners, weights, solver=solver)
    return outcome(distance, result, throw, stats)


def _factorizations(mesh: Mesh, L: SparseMatrix, M: SparseMatrix, plans: _Plans, t_coef, solver: str):
    """`(t, _Factors)`: the factorisations of `M + t L`, its Dirichlet block and the pinned `L` (module docstring)."""
    t = t_coef * jnp.mean(edge_lengths(mesh)) ** 2
    heat_matrix = M + t * L
    heat_dirichlet = None
    if plans.heat is not None:
        heat_dirichlet = factorize(dirichlet_blocks(heat_matrix, plans.heat)[0], method=solver)
    return t, _Factors(
        heat=factorize(heat_matrix, method=solver) if plans.neumann else None,
        heat_dirichlet=heat_dirichlet,
        heat_plan=plans.heat,
        poisson=factorize(dirichlet_blocks(L, plans.poisson)[0], method=solver),
        poisson_plan=plans.poisson,
    )


def _heat_method(mesh: Mesh, factors: _Factors, corners, weights) -> tuple[HeatMethodSteps, RESULTS, dict]:
    """The three steps (module docstring) with kept factorisations: `(steps, result, stats)`."""
    delta = jnp.zeros(mesh.n_vertices, weights.dtype).at[corners.ravel()].add(weights.ravel())
    solutions: list[LinearSolution] = []
    heats = []  # the Neumann and / or the Dirichlet heat flow; their mean
    if factors.heat is not None:
        solutions.append(factors.heat.solve(delta, throw=False))
        heats.append(solutions[-1].value)
    if factors.heat_dirichlet is not None:
        plan = factors.heat_plan
        solutions.append(factors.heat_dirichlet.solve(delta[plan.free], throw=False))
        heats.append(plan.join(solutions[-1].value, jnp.zeros(plan.fixed.shape[0], delta.dtype)))
    u = sum(heats) / len(heats)
    g = gradient(mesh, u)
    norm = safe_norm(g, keepdims=True)
    field = jnp.where(norm > 0, -g / jnp.where(norm > 0, norm, 1.0), 0.0)
    div = divergence(mesh, field)
    plan = factors.poisson_plan
    solutions.append(factors.poisson.solve(-div[plan.free], throw=False))
    phi = plan.join(solutions[-1].value, jnp.zeros(plan.fixed.shape[0], div.dtype))
    at_sources = jnp.mean(jnp.sum(phi[corners] * weights, axis=1))
    steps = HeatMethodSteps(heat=u, field=field, divergence=div, distance=phi - at_sources)
    stats = {
        "residual": jnp.max(jnp.stack([solution.residual for solution in solutions])),
        "num_steps": sum(solution.num_steps for solution in solutions),
    }
    return steps, first_failure(*(solution.result for solution in solutions)), stats


@kernel(static_argnames=("solver",))
def _factor(mesh: Mesh, L, M, plans: _Plans, t_coef, *, solver: str):
    return _factorizations(mesh, L, M, plans, t_coef, solver)


@kernel
def _query(mesh: Mesh, factors: _Factors, corners, weights):
    return _heat_method(mesh, factors, corners, weights)


# Factorisations and one query in one compiled program per mesh size and source count.
@kernel(static_argnames=("solver",))
def _build_and_query(mesh: Mesh, L, M, plans: _Plans, t_coef, corners, weights, *, solver: str):
    _, factors = _factorizations(mesh, L, M, plans, t_coef, solver)
    steps, result, stats = _heat_method(mesh, factors, corners, weights)
    return steps.distance, result, stats


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
