"""Geodesic distance on a point cloud by the heat method, on its tufted intrinsic Delaunay triangulation.

As geometry-central's `PointCloudHeatSolver` ("we basically just run the mesh version on the tufted
triangulation of the point cloud"), potpourri3d's `PointCloudHeatSolver(P).compute_distance(i)`:
the heat method of Crane, Weischedel & Wardetzky 2013 (`ddgjax.geodesics._heat`) on the faces of
`point_cloud_triangulation(points)`, an intrinsic triangulation known by its edge lengths only, so
the gradient step works per face from lengths:

1. `(M + t L) u = delta_sources`, `L`, `M` = `point_cloud_laplacian`, `t = t_coef * h^2` with `h`
   the mean edge length of the flipped tufted cover (geometry-central's time scale);
2. per cover face `f`, with `K_f` its cotan stiffness matrix (`(K_f u)_a = 1/2 sum cot(c) (u_a - u_b)`
   over its other corners `b`, `c` the corner opposite `ab`): `|grad u|_f = sqrt(u^T K_f u / A_f)`,
   and the integrated divergence of `X = -grad u / |grad u|` at a corner `a` is
   `-int_f X . grad phi_a = (K_f u)_a / |grad u|_f` (0 where `grad u` vanishes);
3. `L phi = -div` with one point pinned per connected component, divided by the cover's
   multiplicity as `L` is;
4. shifted as the mesh heat method shifts its vertex sources (`ddgjax.geodesics._heat._shift`, which
   takes a `Mesh` for sources inside faces): each component holding a source has its minimum, or
   its sources' mean level where lower, at 0; other components are `inf`.

So the distance is exactly the mesh heat method run on that intrinsic triangulation with the
barycentric mass and the Neumann heat flow (the cover is closed), differentiable in the points for
the fixed triangulation. potpourri3d shifts by the sources' mean instead (the same with one source).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import at_top_level, kernel
from .._errors import DDGInputError
from .._indexing import take_rows
from .._numerics import safe_sqrt
from .._options import check_solver
from .._results import Solution, first_failure, outcome
from ..geodesics._heat import _factor_held, _solve_held
from ..mesh import corner_cotangents_from_lengths_sq, face_areas_from_lengths_sq
from ..solve import Factorization
from ..solve._linear import cholmod_analysis, kept_analysis
from ..sparse import DirichletPlan, dirichlet_plan
from ._laplacian import _COVER_MULTIPLICITY, _triangulation_for, laplacian_and_mass_from_lengths_sq
from ._triangulation import PointCloudTriangulation, check_points


class PointCloudHeatSolver(eqx.Module):
    """The heat method's kept factorisations for one point cloud: `solver.distance(sources)` per query.

    Made by `point_cloud_heat_solver(points, ...)` (module docstring); a pytree.

    Attributes:
        points: `(n, 3)` the positions.
        triangulation: the cloud's `PointCloudTriangulation`.
        t: the heat flow's time `t_coef * h^2`.
        heat: factorisation of `M + t L` (its free block when some points belong to no triangle).
        heat_plan: the `DirichletPlan` holding those points at 0, else `None`.
        poisson: factorisation of `L` with one point per component pinned.
        poisson_plan: the pins' `DirichletPlan`.
        components: `(n,)` each point's connected component.
        cotangents: `(n_cover, 3)` each cover face's corner cotangents.
        areas: `(n_cover,)` each cover face's area.
    """

    points: Float[Array, "n 3"]
    triangulation: PointCloudTriangulation
    t: Float[Array, ""]
    heat: Factorization
    heat_plan: DirichletPlan | None
    poisson: Factorization
    poisson_plan: DirichletPlan
    components: Int[Array, " n"]
    cotangents: Float[Array, "n_cover 3"]
    areas: Float[Array, " n_cover"]

    def distance(self, sources, *, throw: bool = True) -> Float[Array, " n"] | Solution:
        """Geodesic distance from the source points (indices, `(m,)` or one integer) to every point, `(n,)`.

        `>= 0`, `inf` on components no source reaches. `throw=False` returns a `ddgjax.Solution`
        (`stats`: the largest relative residual of the two solves and their CG iterations).
        """
        corners, weights = _sources(self.points.shape[0], sources, self.points.dtype)
        distance, result, stats = _query(self, corners, weights)
        return outcome(distance, result, throw, stats)


def point_cloud_heat_solver(
    points: ArrayLike,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
) -> PointCloudHeatSolver:
    """Factor the heat method's systems for a point cloud once (module docstring); query with `.distance(sources)`.

    Args:
        points: `(n, 3)` finite positions.
        n_neighbors: the neighbourhood size of the triangulation (keyword-only; default 30).
        t_coef: the heat flow's time in units of `h^2`, `h` the mean edge length of the tufted
            triangulation (keyword-only; default 1, potpourri3d's `t_coef`).
        mollify_factor: the triangulation's mollification (keyword-only; default `1e-5`).
        triangulation: `point_cloud_triangulation(points, ...)` to reuse (needed under `jit` / `grad`).
        solver: the backend of the kept factorisations (`ddgjax.LINEAR_SOLVERS`).

    Returns:
        `PointCloudHeatSolver`.

    potpourri3d: `PointCloudHeatSolver(P, t_coef=1.0)` (its neighbourhood size is fixed at 30).
    """
    points = check_points(points)
    check_solver(solver)
    if isinstance(t_coef, bool) or not isinstance(t_coef, (int, float, np.integer, np.floating)) or not t_coef > 0:
        raise DDGInputError(f"t_coef: expected a positive number, got {t_coef!r}")
    triangulation = _triangulation_for(points, triangulation, n_neighbors=n_neighbors, mollify_factor=mollify_factor)
    heat_plan, poisson_plan, components = _plans(triangulation, triangulation.plan.pattern)
    with cholmod_analysis(kept_analysis(points.shape[0])):
        factors = _factor(points, triangulation, heat_plan, poisson_plan, float(t_coef), solver=solver)
        if at_top_level():
            jax.block_until_ready(factors)
    t, heat, poisson, cotangents, areas = factors
    return PointCloudHeatSolver(
        points=points,
        triangulation=triangulation,
        t=t,
        heat=heat,
        heat_plan=heat_plan,
        poisson=poisson,
        poisson_plan=poisson_plan,
        components=components,
        cotangents=cotangents,
        areas=areas,
    )


def point_cloud_heat_distance(
    points: ArrayLike,
    sources,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, " n"] | Solution:
    """Geodesic distance on a point cloud from source points, by the heat method on its tufted triangulation, `(n,)`.

    `point_cloud_heat_solver(points, ...).distance(sources)` (module docstring): first-order
    accurate in the point spacing; `>= 0` with minimum 0 on each component holding a source, `inf`
    on the others. Differentiable in `points` for a fixed `triangulation`.

    Args:
        points: `(n, 3)` finite positions.
        sources: point indices, `(m,)` integers or one integer.
        n_neighbors, t_coef, mollify_factor, triangulation, solver: as `point_cloud_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(n,)` distances.

    potpourri3d: `PointCloudHeatSolver(P, t_coef=1.0).compute_distance(i)` /
    `compute_distance_multisource(idx)` (which shifts by the sources' mean rather than to 0).
    """
    _sources(np.shape(points)[0] if np.ndim(points) == 2 else 0, sources, np.float64)  # refuse bad sources first
    solver_ = point_cloud_heat_solver(
        points, n_neighbors=n_neighbors, t_coef=t_coef, mollify_factor=mollify_factor, triangulation=triangulation, solver=solver
    )
    return solver_.distance(sources, throw=throw)


def _plans(triangulation: PointCloudTriangulation, pattern) -> tuple[DirichletPlan | None, DirichletPlan, Int[Array, " n"]]:
    """`(heat_plan, poisson_plan, components)` on the host: points in no triangle held, one pin per component."""
    n = triangulation.n_points
    faces = np.asarray(triangulation.faces)
    rows, cols = faces[:, [0, 1, 2]].reshape(-1), faces[:, [1, 2, 0]].reshape(-1)
    graph = scipy.sparse.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    unreferenced = np.setdiff1d(np.arange(n), faces.reshape(-1))
    _, pins = np.unique(labels, return_index=True)
    return (
        dirichlet_plan(pattern, unreferenced) if unreferenced.size else None,
        dirichlet_plan(pattern, pins),
        jnp.asarray(labels.astype(np.int32)),
    )


@kernel(static_argnames=("solver",))
def _factor(points, triangulation, heat_plan, poisson_plan, t_coef, *, solver: str):
    lengths_sq = triangulation.face_lengths_sq(points)
    L, M = laplacian_and_mass_from_lengths_sq(lengths_sq, triangulation)
    t = t_coef * jnp.mean(safe_sqrt(lengths_sq)) ** 2  # each cover edge is in two faces: the mean over edges
    areas = face_areas_from_lengths_sq(lengths_sq)
    cotangents = corner_cotangents_from_lengths_sq(lengths_sq, areas=areas)
    return t, _factor_held(M + t * L, heat_plan, solver), _factor_held(L, poisson_plan, solver), cotangents, areas


@kernel
def _query(solver: PointCloudHeatSolver, corners, weights):
    n = solver.points.shape[0]
    delta = jnp.zeros(n, weights.dtype).at[corners[:, 0]].add(weights[:, 0])
    heat, u = _solve_held(solver.heat, solver.heat_plan, delta)
    faces = solver.triangulation.faces
    face_u = take_rows(u, faces)
    # (K_f u)_a = 1/2 [cot_c (u_a - u_b) + cot_b (u_a - u_c)] for the corners (a, b, c) in cyclic order.
    following, opposite = jnp.roll(face_u, -1, axis=1), jnp.roll(face_u, 1, axis=1)
    cot = solver.cotangents
    stiffness_u = 0.5 * (jnp.roll(cot, 1, axis=1) * (face_u - following) + jnp.roll(cot, -1, axis=1) * (face_u - opposite))
    energy = 0.5 * jnp.sum(cot * (following - opposite) ** 2, axis=1)  # u^T K_f u = A |grad u|^2
    norm_sq = jnp.where(solver.areas > 0, energy / jnp.where(solver.areas > 0, solver.areas, 1.0), 0.0)
    norm = safe_sqrt(norm_sq)
    corner_div = jnp.where(norm[:, None] > 0, stiffness_u / jnp.where(norm > 0, norm, 1.0)[:, None], 0.0)
    div = jax.ops.segment_sum(corner_div.reshape(-1), faces.reshape(-1), num_segments=n) / _COVER_MULTIPLICITY
    poisson, phi = _solve_held(solver.poisson, solver.poisson_plan, -div)
    distance = _shift(phi, solver.components, corners[:, 0])
    stats = {"residual": jnp.maximum(heat.residual, poisson.residual), "num_steps": heat.num_steps + poisson.num_steps}
    return distance, first_failure(heat.result, poisson.result), stats


def _shift(phi, components, sources) -> Float[Array, " n"]:
    """Step 4 (module docstring) for source points: per component `phi - min(min phi, mean phi at its sources)`, or `inf`."""
    n = phi.shape[0]
    source_components = components[sources]
    level = jax.ops.segment_sum(phi[sources], source_components, n)
    count = jax.ops.segment_sum(jnp.ones_like(phi[sources]), source_components, n)
    level = jnp.where(count > 0, level / jnp.where(count > 0, count, 1.0), jnp.inf)
    shift = jnp.minimum(jax.ops.segment_min(phi, components, n), level)
    reached = jnp.zeros(n, bool).at[source_components].set(True)
    return jnp.where(reached[components], phi - shift[components], jnp.inf)


def _sources(n: int, sources, dtype) -> tuple[np.ndarray, np.ndarray]:
    """`(corners (m, 3), weights (m, 3))` of source points as the mesh heat method takes them: `(i, i, i)`, `(1, 0, 0)`."""
    indices = np.atleast_1d(np.asarray(sources))
    if indices.ndim != 1 or indices.size == 0 or not np.issubdtype(indices.dtype, np.integer):
        raise DDGInputError(f"sources: expected point indices (a non-empty 1-d integer array), got {sources!r}")
    if indices.min() < 0 or indices.max() >= n:
        raise DDGInputError(f"sources: point indices must lie in [0, {n}), got {indices[(indices < 0) | (indices >= n)][:5]}")
    weights = np.zeros((indices.size, 3), dtype)
    weights[:, 0] = 1.0
    return np.repeat(indices[:, None], 3, axis=1), weights
